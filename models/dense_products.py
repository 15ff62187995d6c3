"""CasADi's dense matrix product in generated C, rewritten to run at the core's speed with the same doubles.

CasADi's code generator writes every dense product ``z += x y`` (MX
multiplications; x (nrow_x, ncol_x), y (ncol_x, ncol_y), column-major; ``tr``:
z += xᵀ y) through one helper, ``casadi_mtimes_dense``. Its loops sum each
entry of z in one dependent chain of adds, storing z after every one, so a
matrix times a vector runs at one add per add latency, not per vector lane:
the exported NMPC's QP residuals (``rti_recover``: H v, C v and Cᵀ λ) took
14 % of the pendulum's scenario-tree step that way.

`faster_products` replaces that helper in generated code by one that adds the
same products to each entry of z in the same order (k ascending, from z's
value), but keeps four entries' sums in registers at once where an entry is
a dot product (xᵀ y, or x a single row: one loop serves both), and runs the
other case (z += x y, x with more than one row) with k outside, along x's
columns, which the compiler vectorizes. Compiled without floating-point
contraction (ISO C, as the exported controllers' programs, or
-ffp-contract=off) every result is CasADi's double, bit for bit; where GNU C
fuses a multiply and an add, it may fuse them in one loop and not in the
other, and an entry differs by that rounding. CasADi never passes a z that
overlaps x or y (a multiplication works in place on its addend only).
The replacement applies only where the helper is CasADi 3.8's, text for
text; other code is returned unchanged (and slower).
"""

from __future__ import annotations

#: ``casadi_mtimes_dense`` as CasADi 3.8's code generator writes it.
CASADI = """void casadi_mtimes_dense(const casadi_real* x, casadi_int nrow_x, casadi_int ncol_x,
    const casadi_real* y, casadi_int ncol_y, casadi_real* z, casadi_int tr) {
  casadi_int i, j, k;
  if (tr) {
    for (i=0; i<ncol_y; ++i) {
      for (j=0; j<ncol_x; ++j) {
        for (k=0; k<nrow_x; ++k) {
          z[j + i*ncol_x] += x[k + j*nrow_x] * y[k + i*nrow_x];
        }
      }
    }
  } else {
    for (i=0; i<ncol_y; ++i) {
      for (j=0; j<nrow_x; ++j) {
        for (k=0; k<ncol_x; ++k) {
          z[j + i*nrow_x] += x[j + k*nrow_x] * y[k + i*ncol_x];
        }
      }
    }
  }
}
"""

#: The same products, each entry of z summed in CasADi's order. Where an entry is a dot product (tr, or x a
#: single row) four run at once: z_j += sum_k v[k] a_j[k], a_j = a + j len (tr: v = y's column i, a = x;
#: x a row: v = x, a = y); otherwise k is outside and the entries of z's column inside.
FASTER = """void casadi_mtimes_dense(const casadi_real* x, casadi_int nrow_x, casadi_int ncol_x,
    const casadi_real* y, casadi_int ncol_y, casadi_real* z, casadi_int tr) {
  /* codesign-control (models.dense_products): each entry summed in CasADi's order, four at a time */
  casadi_int i, j, k;
  if (tr || nrow_x == 1) {
    const casadi_int len = tr ? nrow_x : ncol_x, count = tr ? ncol_x : ncol_y, columns = tr ? ncol_y : 1;
    const casadi_real* a = tr ? x : y;
    for (i=0; i<columns; ++i) {
      const casadi_real* v = tr ? y + i*nrow_x : x;
      casadi_real* zi = z + i*count;
      for (j=0; j+4<=count; j+=4) {
        const casadi_real *a0 = a + j*len, *a1 = a0 + len, *a2 = a1 + len, *a3 = a2 + len;
        casadi_real s0 = zi[j], s1 = zi[j+1], s2 = zi[j+2], s3 = zi[j+3];
        for (k=0; k<len; ++k) {
          s0 += a0[k] * v[k];
          s1 += a1[k] * v[k];
          s2 += a2[k] * v[k];
          s3 += a3[k] * v[k];
        }
        zi[j] = s0; zi[j+1] = s1; zi[j+2] = s2; zi[j+3] = s3;
      }
      for (; j<count; ++j) {
        const casadi_real* aj = a + j*len;
        casadi_real s = zi[j];
        for (k=0; k<len; ++k) s += aj[k] * v[k];
        zi[j] = s;
      }
    }
  } else {
    for (i=0; i<ncol_y; ++i) {
      casadi_real* zi = z + i*nrow_x;
      for (k=0; k<ncol_x; ++k) {
        const casadi_real* xk = x + k*nrow_x;
        const casadi_real yk = y[k + i*ncol_x];
        for (j=0; j<nrow_x; ++j) zi[j] += xk[j] * yk;
      }
    }
  }
}
"""


def faster_products(code: str) -> str:
    """`code` (C from CasADi's code generator) with its ``casadi_mtimes_dense`` replaced by `FASTER` (the
    same sums in the same order, sooner); unchanged when it has none, or not CasADi 3.8's."""
    return code.replace(CASADI, FASTER, 1)
