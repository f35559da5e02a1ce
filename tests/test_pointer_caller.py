"""A compiled function that calls kernels through their addresses (``_jit.PointerCaller``).

The compiled closed loop calls the simulator's and the controller's steps so, that it does not compile them
into its own machine code again (numba links a callee it calls by name, and optimises and emits it again).
Here, on two small kernels: the same results as calling them from Python, the kernels typed as function
pointers in the caller's compiled signature (not as the kernels themselves, which numba would link in), one
specialisation of each kernel shared with Python's calls, and a new specialisation for new argument types.
"""

from __future__ import annotations

import numpy as np
from numba import types

from omnirotor._jit import _PURE_PYTHON, PointerCaller, jit_entry


@jit_entry
def _scale(x, f: float) -> float:
    s = 0.0
    for i in range(x.shape[0]):
        x[i] *= f
        s += x[i]
    return s


@jit_entry
def _shift(x, d: float) -> None:
    for i in range(x.shape[0]):
        x[i] += d


def _loop(scale, shift, x, n: int, f: float, d: float) -> float:
    total = 0.0
    for _ in range(n):
        shift(x, d)
        total += scale(x, f)
    return total


def _kernel_args(x, n, f, d) -> tuple:
    return (x, f), (x, d)


_compiled_loop = PointerCaller(_loop, _kernel_args)


def _reference(x: np.ndarray, n: int, f: float, d: float) -> float:
    total = 0.0
    for _ in range(n):
        x += d
        x *= f
        total += float(np.sum(x))  # the same order of additions as the kernel for 3 entries
    return total


def test_the_kernels_called_through_pointers_give_the_python_results() -> None:
    x = np.array([1.0, -2.0, 0.5])
    y = x.copy()
    got = _compiled_loop((_scale, _shift), x, 5, 0.5, 0.25)
    want = 0.0
    for _ in range(5):
        _shift(y, 0.25)
        want += _scale(y, 0.5)
    assert got == want
    np.testing.assert_array_equal(x, y)
    z = np.array([1.0, -2.0, 0.5])
    assert got == _reference(z, 5, 0.5, 0.25)


def test_the_kernels_are_function_pointers_in_the_callers_signature_and_compiled_once() -> None:
    if _PURE_PYTHON:
        return  # nothing is compiled
    x = np.ones(4)
    _compiled_loop((_scale, _shift), x, 2, 2.0, 1.0)
    sigs = [s for s in _compiled_loop.signatures if s[2] == types.float64[::1]]
    assert len(sigs) == 1
    assert all(isinstance(t, types.FunctionType) for t in sigs[0][:2])  # called through an address, not linked
    _scale(x, 1.0)  # from Python: the specialisation the loop calls, no other
    for kernel in (_scale, _shift):
        assert [s for s in kernel.signatures if s[0] == types.float64[::1]] == [(types.float64[::1], types.float64)]


def test_new_argument_types_compile_a_new_specialisation() -> None:
    if _PURE_PYTHON:
        return
    x = np.ones(3, dtype=np.float32)
    got = _compiled_loop((_scale, _shift), x, 1, 2.0, 1.0)
    assert got == 12.0
    assert (types.float32[::1], types.float64) in _scale.signatures
    assert any(s[2] == types.float32[::1] for s in _compiled_loop.signatures)
