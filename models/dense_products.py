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
a dot product, and runs the other case (z += x y, x with more than one row)
with k outside, along x's columns, which the compiler vectorizes. Compiled
without floating-point contraction (ISO C, as the exported controllers'
programs, or -ffp-contract=off) every result is CasADi's double, bit for
bit; where GNU C fuses a multiply and an add, it may fuse them in one loop
and not in the other, and an entry differs by that rounding. CasADi never passes a z that
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

#: The same products, each entry of z summed in CasADi's order: dot products four entries at a time
#: (tr, and x a single row), otherwise k outside and the entries of z's column inside.
FASTER = """void casadi_mtimes_dense(const casadi_real* x, casadi_int nrow_x, casadi_int ncol_x,
    const casadi_real* y, casadi_int ncol_y, casadi_real* z, casadi_int tr) {
  /* codesign-control (models.dense_products): each entry summed in CasADi's order, four at a time */
  casadi_int i, j, k;
  if (tr) {
    for (i=0; i<ncol_y; ++i) {
      const casadi_real* yi = y + i*nrow_x;
      casadi_real* zi = z + i*ncol_x;
      for (j=0; j+4<=ncol_x; j+=4) {
        const casadi_real *x0 = x + j*nrow_x, *x1 = x0 + nrow_x, *x2 = x1 + nrow_x, *x3 = x2 + nrow_x;
        casadi_real s0 = zi[j], s1 = zi[j+1], s2 = zi[j+2], s3 = zi[j+3];
        for (k=0; k<nrow_x; ++k) {
          s0 += x0[k] * yi[k];
          s1 += x1[k] * yi[k];
          s2 += x2[k] * yi[k];
          s3 += x3[k] * yi[k];
        }
        zi[j] = s0; zi[j+1] = s1; zi[j+2] = s2; zi[j+3] = s3;
      }
      for (; j<ncol_x; ++j) {
        const casadi_real* xj = x + j*nrow_x;
        casadi_real s = zi[j];
        for (k=0; k<nrow_x; ++k) s += xj[k] * yi[k];
        zi[j] = s;
      }
    }
  } else if (nrow_x == 1) {
    for (i=0; i+4<=ncol_y; i+=4) {
      const casadi_real *y0 = y + i*ncol_x, *y1 = y0 + ncol_x, *y2 = y1 + ncol_x, *y3 = y2 + ncol_x;
      casadi_real s0 = z[i], s1 = z[i+1], s2 = z[i+2], s3 = z[i+3];
      for (k=0; k<ncol_x; ++k) {
        s0 += x[k] * y0[k];
        s1 += x[k] * y1[k];
        s2 += x[k] * y2[k];
        s3 += x[k] * y3[k];
      }
      z[i] = s0; z[i+1] = s1; z[i+2] = s2; z[i+3] = s3;
    }
    for (; i<ncol_y; ++i) {
      const casadi_real* yi = y + i*ncol_x;
      casadi_real s = z[i];
      for (k=0; k<ncol_x; ++k) s += x[k] * yi[k];
      z[i] = s;
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
