"""srmpc.pinned_kernels: torch's MKL ops rerouted to NumPy give torch's results within a stated bound, in every form.

Each test registers the pinned kernels in this process for its own duration only (the ``routed`` fixture), and
compares with torch's own kernels (MKL) run on the same inputs before. Bounds: :data:`ULP_BOUND` for the unary
functions; for a matrix product of inner size K, the classic forward error bound of a dot product,
``|C - C'| <= 2 K eps (|A| |B|)`` element by element (both results within ``K eps |A||B|`` of the exact one).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from srmpc import pinned_kernels
from srmpc.pinned_kernels import ULP_BOUND, UNARY_FUNCTIONS, PinnedKernelError

DOMAINS = {"log": (0.01, 50.0), "log2": (0.01, 50.0), "log10": (0.01, 50.0), "sqrt": (0.0, 50.0),
           "asin": (-0.99, 0.99), "acos": (-0.99, 0.99), "erfinv": (-0.99, 0.99), "exp": (-20.0, 20.0),
           "tan": (-1.5, 1.5)}
"""Input range per function (default: [-6, 6])."""


@pytest.fixture
def routed():
    """The pinned kernels registered for this test only: torch's own come back afterwards."""
    pinned_kernels.route()
    yield
    pinned_kernels.unroute()


def _inputs(name: str, shape: tuple[int, ...], dtype=torch.float32, seed: int = 0) -> torch.Tensor:
    low, high = DOMAINS.get(name, (-6.0, 6.0))
    generator = torch.Generator().manual_seed(seed)
    return (low + (high - low) * torch.rand(shape, generator=generator, dtype=torch.float64)).to(dtype)


def _ulps(a: torch.Tensor, b: torch.Tensor) -> int:
    """The largest distance in units in the last place between two float tensors of one dtype (nan == nan)."""
    assert a.dtype == b.dtype and a.shape == b.shape
    bits = {torch.float32: np.int32, torch.float64: np.int64}[a.dtype]

    def ordered(t: torch.Tensor) -> np.ndarray:
        raw = t.detach().contiguous().numpy().view(bits).astype(np.int64)
        return np.where(raw < 0, np.iinfo(bits).min - raw, raw)

    both_nan = torch.isnan(a) & torch.isnan(b)
    distance = np.abs(ordered(a) - ordered(b))
    return int(np.where(both_nan.numpy(), 0, distance).max(initial=0))


def _native_then_routed(function, *args):
    """``function(*args)`` with torch's own kernels, then with the pinned ones (registered for the second call)."""
    native = function(*args)
    pinned_kernels.route()
    try:
        pinned = function(*args)
    finally:
        pinned_kernels.unroute()
    return native, pinned


@pytest.mark.parametrize("name", sorted(UNARY_FUNCTIONS))
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_unary_function_within_its_ulp_bound(name, dtype):
    """Contiguous, strided, transposed and 0-dim inputs: within ULP_BOUND of torch's own kernel, same dtype, shape
    and values where torch's are exact."""
    base = _inputs(name, (257, 64), dtype)
    for x in (base, base[::3, ::2], base.t(), base[5, 7]):
        native, pinned = _native_then_routed(lambda t: getattr(torch, name)(t), x)
        assert pinned.dtype == native.dtype and pinned.shape == native.shape
        assert _ulps(pinned, native) <= ULP_BOUND[name], (name, dtype, x.shape, x.stride())


@pytest.mark.parametrize("name", ["exp", "log", "tanh", "sqrt", "erf"])
def test_unary_out_in_place_and_integer_forms(name, routed):
    x = _inputs(name, (33, 5))
    expected = getattr(torch, name)(x)
    out = torch.empty(0)
    assert getattr(torch, name)(x, out=out) is out and torch.equal(out, expected)
    y = x.clone()
    assert getattr(y, f"{name}_")() is y and torch.equal(y, expected)
    strided = x.clone().t()
    getattr(strided, f"{name}_")()
    assert torch.equal(strided, expected.t())
    integers = torch.arange(1, 7)
    result = getattr(torch, name)(integers)
    assert result.dtype == torch.get_default_dtype()
    assert torch.equal(result, getattr(torch, name)(integers.to(torch.float32)))
    with pytest.raises(RuntimeError, match="can't be cast"):
        getattr(integers, f"{name}_")()


def test_foreach_sqrt_as_adam_calls_it(routed):
    tensors = [_inputs("sqrt", (4, 3), seed=s) for s in range(3)]
    roots = torch._foreach_sqrt(tensors)
    assert all(torch.equal(root, t.sqrt()) for root, t in zip(roots, tensors, strict=True))
    copies = [t.clone() for t in tensors]
    torch._foreach_sqrt_(copies)
    assert all(torch.equal(c, r) for c, r in zip(copies, roots, strict=True))


def test_half_types_are_computed_in_float32(routed):
    x = _inputs("tanh", (64,))
    for dtype in (torch.float16, torch.bfloat16):
        assert torch.equal(torch.tanh(x.to(dtype)), torch.tanh(x.to(dtype).to(torch.float32)).to(dtype))


def test_complex_tensors_are_refused_in_one_line(routed):
    for call in (lambda: torch.exp(torch.ones(3, dtype=torch.complex64)),
                 lambda: torch.ones(2, 2, dtype=torch.complex64) @ torch.ones(2, 2, dtype=torch.complex64)):
        with pytest.raises(PinnedKernelError) as error:
            call()
        assert "\n" not in str(error.value) and "complex" in str(error.value)


def _assert_product_close(pinned: torch.Tensor, native: torch.Tensor, bound: torch.Tensor, inner: int,
                          case: str) -> None:
    eps = torch.finfo(native.dtype).eps
    assert pinned.dtype == native.dtype and pinned.shape == native.shape, case
    assert torch.all((pinned - native).abs() <= 2 * inner * eps * bound + torch.finfo(native.dtype).tiny), case


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_matrix_products_within_the_dot_product_bound(dtype):
    """mm, addmm (bias broadcast, alpha, beta), bmm, baddbmm, mv/addmv, dot and matmul, on contiguous and
    transposed operands, at the training's shapes and small ones."""
    a, b = _inputs("", (8192, 64), dtype, 1), _inputs("", (64, 30), dtype, 2)
    bias, batch1, batch2 = _inputs("", (30,), dtype, 3), _inputs("", (3, 7, 40), dtype, 4), _inputs("", (3, 40, 5),
                                                                                                   dtype, 5)
    vector = _inputs("", (64,), dtype, 6)
    cases = {
        "mm": (lambda: torch.mm(a, b), a.abs() @ b.abs(), 64),
        "mm_transposed": (lambda: torch.mm(a.t(), a), a.abs().t() @ a.abs(), 8192),
        "addmm": (lambda: torch.addmm(bias, a, b), a.abs() @ b.abs() + bias.abs(), 65),
        "addmm_scaled": (lambda: torch.addmm(bias, a, b, beta=0.5, alpha=2.0), 2 * (a.abs() @ b.abs()) + bias.abs(),
                         66),
        "linear": (lambda: torch.nn.functional.linear(a, b.t(), bias), a.abs() @ b.abs() + bias.abs(), 65),
        "bmm": (lambda: torch.bmm(batch1, batch2), batch1.abs() @ batch2.abs(), 40),
        "baddbmm": (lambda: torch.baddbmm(torch.ones(3, 7, 5, dtype=dtype), batch1, batch2),
                    batch1.abs() @ batch2.abs() + 1, 41),
        "mv": (lambda: torch.mv(a, vector), a.abs() @ vector.abs(), 64),
        "addmv": (lambda: torch.addmv(bias[:1].expand(8192), a, vector), a.abs() @ vector.abs() + bias[:1].abs(), 65),
        "dot": (lambda: torch.dot(a[:, 0], a[:, 1]), a[:, 0].abs() @ a[:, 1].abs(), 8192),
        "matmul_3d": (lambda: batch1 @ batch2[0], batch1.abs() @ batch2[0].abs(), 40),
    }
    for name, (product, bound, inner) in cases.items():
        native, pinned = _native_then_routed(product)
        _assert_product_close(pinned, native, bound, inner, name)


def test_matrix_products_run_in_numpy(routed):
    """The bytes are NumPy's (OpenBLAS), not MKL's: the pinned product equals np.matmul exactly."""
    a, b = _inputs("", (512, 64), seed=1), _inputs("", (64, 64), seed=2)
    assert np.array_equal(torch.mm(a, b).numpy(), np.matmul(a.numpy(), b.numpy()))


def test_matrix_product_forms(routed):
    a, b, c = _inputs("", (6, 4), seed=1), _inputs("", (4, 3), seed=2), _inputs("", (6, 3), seed=3)
    expected = torch.addmm(c, a, b)
    out = torch.empty(1)
    assert torch.addmm(c, a, b, out=out) is out and torch.equal(out, expected)
    in_place = c.clone()
    assert in_place.addmm_(a, b) is in_place and torch.equal(in_place, expected)
    out = torch.empty(6, 3)
    assert torch.equal(torch.mm(a, b, out=out), a @ b)
    with_nan = torch.full((6, 3), float("nan"))
    assert torch.equal(torch.addmm(with_nan, a, b, beta=0), torch.mm(a, b))  # BLAS: beta 0 ignores C
    integers = torch.arange(12).reshape(3, 4), torch.arange(8).reshape(4, 2)
    assert torch.equal(integers[0] @ integers[1], torch.from_numpy(integers[0].numpy() @ integers[1].numpy()))
    scalar = torch.dot(a[:, 0], a[:, 1])
    assert scalar.dim() == 0 and scalar.dtype == torch.float32


def test_autograd_through_the_pinned_kernels():
    """A linear layer, tanh, exp, log and sqrt: the same loss and gradients as torch's own kernels within float32
    rounding (the derivative formulas run above the CPU key and call the pinned kernels again)."""
    def loss_and_grads():
        x = _inputs("", (256, 30), seed=1).requires_grad_()
        layer = torch.nn.Linear(30, 64)
        with torch.no_grad():  # pre-activations of order 1: tanh unsaturated, so 1 - tanh^2 is well conditioned
            layer.weight.copy_(0.02 * _inputs("", (64, 30), seed=2))
            layer.bias.copy_(0.1 * _inputs("", (64,), seed=3))
        hidden = layer(x).tanh()
        loss = (hidden.exp().sqrt() + (hidden + 2).log()).sum()
        loss.backward()
        return loss.detach(), x.grad, layer.weight.grad, layer.bias.grad

    native, pinned = _native_then_routed(loss_and_grads)
    # sums of 64 to 16384 terms in another order: float32 rounding of that size
    for n, p in zip(native, pinned, strict=True):
        torch.testing.assert_close(p, n, rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("mode", ["reduced", "complete", "r"])
def test_qr_and_the_orthogonal_initialisation(mode):
    """Q and R as torch's (LAPACK's sign convention), batched; orthogonal_ gives an orthogonal matrix."""
    A = _inputs("", (2, 64, 30), torch.float32, 7)
    native, pinned = _native_then_routed(lambda m: torch.linalg.qr(m, mode=mode), A)
    for n, p in zip(native, pinned, strict=True):
        assert p.shape == n.shape and p.dtype == n.dtype
        torch.testing.assert_close(p, n, rtol=1e-4, atol=1e-5)
    q, r = torch.empty(0), torch.empty(0)
    pinned_kernels.route()
    try:
        torch.linalg.qr(A[0], out=(q, r))
        weight = torch.empty(64, 30)
        torch.nn.init.orthogonal_(weight, generator=torch.Generator().manual_seed(0))
    finally:
        pinned_kernels.unroute()
    torch.testing.assert_close(q @ r, A[0], rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(weight.t() @ weight, torch.eye(30), rtol=0, atol=1e-5)
