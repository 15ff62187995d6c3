"""The rewritten dense product gives CasADi's own doubles, and generated code uses it."""

import ctypes

import casadi as ca
import numpy as np
import pytest

import models.compile as mc
from models import dense_products, export

HARNESS = """typedef double casadi_real;
typedef long long int casadi_int;
#define casadi_mtimes_dense casadis
{casadi}#undef casadi_mtimes_dense
#define casadi_mtimes_dense ours
{faster}"""


@pytest.fixture(scope="module", params=["no contraction", "project flags"])
def kernels(request):
    """CasADi's helper and ours, compiled into one library: without floating-point contraction (as ISO C
    builds, the exported controllers' programs) or with the project's flags (GNU C: a multiply and add
    may be fused, differently in the two loops)."""
    source = HARNESS.format(casadi=dense_products.CASADI, faster=dense_products.FASTER)
    flags = (*mc.FLAGS, "-ffp-contract=off") if request.param == "no contraction" else mc.FLAGS
    library = mc.load_library({"products.c": source}, flags, fallback=False)
    argtypes = [ctypes.c_void_p, ctypes.c_longlong, ctypes.c_longlong, ctypes.c_void_p, ctypes.c_longlong]
    argtypes += [ctypes.c_void_p, ctypes.c_longlong]
    return request.param, {name: library.function(name, argtypes) for name in ("casadis", "ours")}


def _product(kernel, x, y, z, tr):
    """z (a copy) += x y (or xᵀ y) by `kernel`; x, y, z column-major."""
    out = np.asfortranarray(z.copy())
    x, y = np.asfortranarray(x), np.asfortranarray(y)
    kernel(x.ctypes.data, x.shape[0], x.shape[1], y.ctypes.data, y.shape[1], out.ctypes.data, tr)
    return out


@pytest.mark.parametrize("tr", [0, 1])
@pytest.mark.parametrize("nrow, ncol, ncol_y", [(1, 13, 9), (1, 4, 8), (7, 13, 1), (13, 7, 3), (5, 1, 6), (1, 1, 1)])
def test_every_entry_is_casadis_double(kernels, tr, nrow, ncol, ncol_y):
    """Bit for bit without contraction; with it, within the rounding a fused multiply-add changes."""
    build, kernels = kernels
    rng = np.random.default_rng(nrow * 100 + ncol * 10 + ncol_y)
    x = rng.standard_normal((nrow, ncol)) * 10.0 ** rng.integers(-8, 8, (nrow, ncol))
    y = rng.standard_normal((nrow if tr else ncol, ncol_y))
    z = rng.standard_normal((ncol if tr else nrow, ncol_y))
    theirs, ours = (_product(kernels[k], x, y, z, tr) for k in ("casadis", "ours"))
    if build == "no contraction":
        np.testing.assert_array_equal(ours.view(np.int64), theirs.view(np.int64))  # bit for bit
    else:
        np.testing.assert_allclose(ours, theirs, rtol=0, atol=4 * ncol * np.spacing(np.abs(theirs).max() + 10.0**8))
    # and both are the product (a second method: numpy's)
    np.testing.assert_allclose(ours, z + (x.T if tr else x) @ y, rtol=1e-9, atol=1e-9 * np.abs(x).max())


def test_generated_code_carries_the_rewritten_product_and_still_computes_the_product():
    """With the installed CasADi the helper is found and replaced in both generators (a CasADi whose
    helper differs would leave the code unchanged and fail here, to be looked at)."""
    x, v = ca.MX.sym("x", 7, 13), ca.MX.sym("v", 13)
    f = ca.Function("f", [x, v], [x @ v, (v.T @ x.T).T])
    for code in (mc._generated([f], "p"), export.generated_code([f], "p")):
        assert "casadi_mtimes_dense(" in code and dense_products.CASADI not in code
        assert "models.dense_products" in code
    compiled = mc.jit(f)
    rng = np.random.default_rng(0)
    X, V = rng.standard_normal((7, 13)), rng.standard_normal(13)
    for out in compiled(X, V):
        np.testing.assert_allclose(np.asarray(out).ravel(), X @ V, rtol=1e-12)
