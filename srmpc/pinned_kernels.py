"""torch's float kernels that reach MKL, rerouted to vendor-neutral ones under ``SRMPC_NUMERICS=pinned``.

torch's CPU build links MKL and calls it three ways on a training's path (issue "Byte-identical on Intel and AMD",
measured with ``MKL_VERBOSE=1`` and an op count on an Intel Xeon):

- BLAS: every ``nn.Linear``, forward and backward (``addmm``, ``mm``; ``bmm``, ``addmv``, ``dot`` elsewhere);
- LAPACK: ``linalg_qr`` (``SGEQRF``/``SORGQR``), from ``nn.init.orthogonal_``;
- VML, MKL's vector math: ATen's float ``exp``, ``log``, ``tanh``, ``sqrt``, ``erf``, ``log2``, ``log10`` and the
  other functions of ``ATen/cpu/vml.h`` (``sin``, ``cos``, ``tan``, ``asin``, ``acos``, ``atan``, ``erfc``,
  ``erfinv``; ``trunc`` is exact and stays).

MKL picks its kernels by the CPU's vendor and instruction sets, and even its ``COMPATIBLE`` branch is other code on
an Intel Xeon than on an AMD EPYC: the same training gave other bytes. :func:`route` registers, for torch's ``CPU``
dispatch key, every overload of these ops (functional, in-place ``op_``, ``op.out``) to run in NumPy instead:

=====================  =========================================================================================
op                     runs in
=====================  =========================================================================================
GEMM, GEMV, dot, QR    NumPy's OpenBLAS at the pinned core type (``OPENBLAS_CORETYPE=Haswell``) on one thread
                       (``OPENBLAS_NUM_THREADS=1``), ``numpy.linalg.qr`` (OpenBLAS's LAPACK)
unary functions        NumPy's ufuncs at the pinned SIMD level (``NPY_ENABLE_CPU_FEATURES=X86_V3``) or glibc's
                       libm, which NumPy calls where it has no SIMD loop; ``erf``/``erfc``/``erfinv`` in SciPy's
                       ``special`` (scalar C)
=====================  =========================================================================================

Each is the same code on every x86-64 CPU with AVX2 and FMA: OpenBLAS's Haswell kernels and NumPy's X86_V3 loops
are compiled once and chosen by the pin, not by the CPU; glibc picks its FMA variants on every such CPU.

Autograd is untouched: the ops' derivative formulas run above the ``CPU`` key and call these ops again, so the
backward pass is rerouted too. Supported dtypes: float32 and float64 (float16 and bfloat16 are computed in float32
and rounded); GEMM also on integers (exact in any order), unary functions on integers and bool as torch does (in
the default float dtype). Complex tensors are refused with one line (:class:`PinnedKernelError`); none is on our
paths. Accuracy against torch's MKL kernels: ``tests/test_pinned_kernels.py`` (within :data:`ULP_BOUND`).

Only :mod:`srmpc.numerics` calls :func:`route`, once per process, when torch is imported under the pin.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
import scipy.special
import torch

UNARY_FUNCTIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "exp": np.exp, "log": np.log, "log2": np.log2, "log10": np.log10, "sqrt": np.sqrt, "tanh": np.tanh,
    "sin": np.sin, "cos": np.cos, "tan": np.tan, "asin": np.arcsin, "acos": np.arccos, "atan": np.arctan,
    "erf": scipy.special.erf, "erfc": scipy.special.erfc, "erfinv": scipy.special.erfinv,
}
"""ATen's unary functions that call MKL's VML for float tensors, and the NumPy/SciPy function each runs in."""

MATRIX_OPS = ("mm", "addmm", "bmm", "baddbmm", "addmv", "dot", "vdot", "linalg_qr")
"""ATen's ops whose CPU kernels call MKL's BLAS or LAPACK (``mv`` and ``matmul`` reach them through ``addmv``/``mm``/
``bmm``/``dot``)."""

UNROUTED_MKL_OPS = frozenset({
    "trunc",  # VML, but exact: every implementation gives the same bytes
    "bernoulli_", "exponential_",  # ATen calls MKL's VSL random streams for these on Intel CPUs only
    "addbmm", "_addmm_activation",  # BLAS
    "linalg_cholesky_ex", "cholesky", "cholesky_solve", "cholesky_inverse", "linalg_lu_factor_ex", "linalg_lu",
    "linalg_lu_solve", "lu_unpack", "linalg_solve_ex", "_linalg_solve_ex", "linalg_inv_ex", "_linalg_det",
    "_linalg_slogdet", "_linalg_eigh", "linalg_eig", "_linalg_svd", "linalg_lstsq", "linalg_householder_product",
    "geqrf", "orgqr", "ormqr", "triangular_solve", "linalg_solve_triangular", "linalg_ldl_factor_ex",
    "linalg_ldl_solve",  # LAPACK
    "_fft_r2c", "_fft_c2r", "_fft_c2c",  # MKL's DFTI
})
"""ATen ops whose CPU kernels may reach MKL but that are not rerouted: none is on a training's path
(``tests/test_mkl_off_the_path.py`` counts every op a short training calls and fails if one appears)."""

ULP_BOUND = {"exp": 3, "log": 4, "log2": 4, "log10": 4, "sqrt": 1, "tanh": 4, "sin": 4, "cos": 4, "tan": 4,
             "asin": 4, "acos": 4, "atan": 4, "erf": 4, "erfc": 40, "erfinv": 8}
"""Largest distance in ULPs from torch's own (MKL's) result, per unary function (tests/test_pinned_kernels.py). NumPy's
sqrt is correctly rounded, MKL's within 1 ULP; SciPy's float64 erfc is 33 ULPs from MKL's (the exact value's) far in
its tail (x = 5.9, erfc = 6.8e-17); elsewhere all are within 4."""

_LIBRARIES: list[torch.library.Library] = []
"""The registrations (kept alive: a Library that is collected deregisters its kernels)."""


class PinnedKernelError(RuntimeError):
    """A tensor the pinned kernels do not compute (a complex dtype): one line naming the op and the dtype."""


def is_routed() -> bool:
    """Whether :func:`route` has registered the pinned kernels in this process."""
    return bool(_LIBRARIES)


def route() -> None:
    """Register the pinned kernels for torch's ``CPU`` key (idempotent)."""
    if _LIBRARIES:
        return
    library = torch.library.Library("aten", "IMPL")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "Overriding a previously registered kernel": intended
        for name, function in UNARY_FUNCTIONS.items():
            _register_unary(library, name, function)
        _register_matrix_ops(library)
    _LIBRARIES.append(library)


# --- NumPy views of tensors ------------------------------------------------------------------------------------------

_COMPUTE_DTYPE = {torch.float32: torch.float32, torch.float64: torch.float64, torch.float16: torch.float32,
                  torch.bfloat16: torch.float32}
"""The dtype each float dtype is computed in (half types in float32, as ATen's own kernels do)."""


def _array(tensor: torch.Tensor, dtype: torch.dtype | None = None) -> np.ndarray:
    """A NumPy view of ``tensor`` (a copy if ``dtype`` differs), below autograd."""
    tensor = tensor.detach()
    if dtype is not None and tensor.dtype != dtype:
        tensor = tensor.to(dtype)
    return tensor.numpy()


def _tensor(array: np.ndarray | np.generic, dtype: torch.dtype) -> torch.Tensor:
    """``array`` as a tensor of ``dtype`` (NumPy returns a 0-dim result as a scalar)."""
    return torch.from_numpy(np.asarray(array)).to(dtype)


def _write(out: torch.Tensor, result: torch.Tensor) -> torch.Tensor:
    """``out=`` semantics: resize ``out`` to the result's shape if it differs, then copy (casting) into it."""
    if out.shape != result.shape:
        out.resize_(result.shape)
    out.copy_(result)
    return out


def _check_dtype(op: str, *tensors: torch.Tensor) -> None:
    for tensor in tensors:
        if tensor.is_complex():
            raise PinnedKernelError(f"{op}: complex tensors ({tensor.dtype}) have no pinned kernel under "
                                    f"SRMPC_NUMERICS=pinned; use float32 or float64")


# --- Unary functions --------------------------------------------------------------------------------------------------

def _unary_result(op: str, function: Callable, self: torch.Tensor) -> torch.Tensor:
    """``function`` of ``self`` in torch's result dtype: floats keep theirs (half types via float32), integers and
    bool give the default float dtype."""
    _check_dtype(op, self)
    result_dtype = self.dtype if self.is_floating_point() else torch.get_default_dtype()
    compute = _COMPUTE_DTYPE[result_dtype]
    with np.errstate(all="ignore"):  # torch returns nan/inf silently, as MKL's VML_ERRMODE_IGNORE does
        return _tensor(function(_array(self, compute)), result_dtype)


def _register_unary(library: torch.library.Library, name: str, function: Callable) -> None:
    def functional(self):
        return _unary_result(name, function, self)

    def in_place(self):
        if not self.is_floating_point():
            raise RuntimeError(f"result type Float can't be cast to the desired output type {self.dtype}")
        return self.copy_(_unary_result(name, function, self))

    def out_form(self, *, out):
        return _write(out, _unary_result(name, function, self))

    library.impl(name, functional, "CPU")
    library.impl(f"{name}_", in_place, "CPU")
    library.impl(f"{name}.out", out_form, "CPU")
    if name == "sqrt":  # Adam's (foreach=True) square root of its second moments
        def foreach(tensors):
            return [functional(tensor) for tensor in tensors]

        def foreach_in_place(tensors):
            for tensor in tensors:
                in_place(tensor)

        library.impl("_foreach_sqrt", foreach, "CPU")
        library.impl("_foreach_sqrt_", foreach_in_place, "CPU")


# --- BLAS and LAPACK --------------------------------------------------------------------------------------------------

def _matmul(op: str, a: torch.Tensor, b: torch.Tensor) -> np.ndarray:
    """``a @ b`` in NumPy, a fresh array (OpenBLAS's sgemm/dgemm/gemv/dot for floats; NumPy's exact loops for
    integers), in the compute dtype (half types in float32)."""
    _check_dtype(op, a, b)
    if a.dtype != b.dtype:
        raise RuntimeError(f"{op}: expected both operands to have the same dtype, got {a.dtype} and {b.dtype}")
    compute = _COMPUTE_DTYPE.get(a.dtype, a.dtype)
    return np.asarray(np.matmul(_array(a, compute), _array(b, compute)))


def _scaled_sum(op: str, self: torch.Tensor, product: np.ndarray, beta, alpha, dtype: torch.dtype) -> torch.Tensor:
    """``beta * self + alpha * product`` as BLAS defines it, in place in ``product``: ``self`` ignored when ``beta``
    is 0 (even a NaN in it), no multiplication by a factor of 1."""
    _check_dtype(op, self)
    if alpha != 1:
        product *= alpha
    if beta != 0:
        addend = _array(self, _COMPUTE_DTYPE.get(self.dtype, self.dtype))
        product += addend if beta == 1 else addend * beta
    return _tensor(product, dtype)


def _register_matrix_ops(library: torch.library.Library) -> None:
    def mm(self, mat2):
        return _tensor(_matmul("mm", self, mat2), self.dtype)

    def addmm(self, mat1, mat2, *, beta=1, alpha=1):
        return _scaled_sum("addmm", self, _matmul("addmm", mat1, mat2), beta, alpha, mat1.dtype)

    def bmm(self, mat2):
        return _tensor(_matmul("bmm", self, mat2), self.dtype)

    def baddbmm(self, batch1, batch2, *, beta=1, alpha=1):
        return _scaled_sum("baddbmm", self, _matmul("baddbmm", batch1, batch2), beta, alpha, batch1.dtype)

    def addmv(self, mat, vec, *, beta=1, alpha=1):
        return _scaled_sum("addmv", self, _matmul("addmv", mat, vec), beta, alpha, mat.dtype)

    def dot(self, tensor):
        return _tensor(_matmul("dot", self, tensor), self.dtype)

    def vdot(self, other):
        return _tensor(_matmul("vdot", self, other), self.dtype)  # real dtypes only: vdot is dot

    functionals = {"mm": mm, "addmm": addmm, "bmm": bmm, "baddbmm": baddbmm, "addmv": addmv, "dot": dot, "vdot": vdot}
    for name, functional in functionals.items():
        library.impl(name, functional, "CPU")
        library.impl(f"{name}.out", _out_form(functional), "CPU")
    for name in ("addmm", "baddbmm", "addmv"):
        library.impl(f"{name}_", _in_place_form(functionals[name]), "CPU")
    library.impl("linalg_qr", _linalg_qr, "CPU")
    library.impl("linalg_qr.out", _linalg_qr_out, "CPU")


def _out_form(functional: Callable) -> Callable:
    def out_form(*args, out, **kwargs):
        return _write(out, functional(*args, **kwargs))
    return out_form


def _in_place_form(functional: Callable) -> Callable:
    def in_place(self, *args, **kwargs):
        return self.copy_(functional(self, *args, **kwargs))
    return in_place


def _linalg_qr(A: torch.Tensor, mode: str = "reduced") -> tuple[torch.Tensor, torch.Tensor]:
    """QR by NumPy's LAPACK (OpenBLAS's ``geqrf``/``orgqr``), batched over leading dimensions like torch's."""
    _check_dtype("linalg_qr", A)
    if mode not in ("reduced", "complete", "r"):
        raise RuntimeError(f"qr received unrecognized mode '{mode}' but expected one of 'reduced' (default), 'r', "
                           f"or 'complete'")
    compute = _COMPUTE_DTYPE.get(A.dtype)
    if compute is None:
        raise PinnedKernelError(f"linalg_qr: dtype {A.dtype} has no pinned kernel; use float32 or float64")
    if mode == "r":
        r = np.linalg.qr(_array(A, compute), mode="r")
        return torch.empty(0, dtype=A.dtype), _tensor(r, A.dtype)
    q, r = np.linalg.qr(_array(A, compute), mode=mode)
    return _tensor(q, A.dtype), _tensor(r, A.dtype)


def _linalg_qr_out(A: torch.Tensor, mode: str = "reduced", *, Q: torch.Tensor, R: torch.Tensor):
    q, r = _linalg_qr(A, mode)
    return _write(Q, q), _write(R, r)


def unroute() -> None:
    """Deregister the pinned kernels: torch's own (MKL's) are back (for tests that compare the two in one process)."""
    while _LIBRARIES:
        _LIBRARIES.pop()._destroy()
