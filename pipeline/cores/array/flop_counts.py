"""FLOP accounting of the angular innovation: the paper's analytic model and a counter of what
our kernels actually execute.

Ryu, Lee & Lee (2001), section IV; see ``docs/papers/array.md``. Convention of
the paper (Matlab's ``flops``): a real addition, subtraction, multiplication or division is one
FLOP, a complex multiplication 6, a complex addition 2; only multiplications/divisions and
additions/subtractions are counted (no exponentials, square roots or data movement).

Analytic model, per scan, all N targets (M sensors)::

    proposed: 2(2N)³ + 16 M N² + 8 M² N + (16 M² + 8 M) · N        (N³ growth)
    Ryu:     [2(2N+1)³ + 8 M (2N+1)² + 4 M (2N+1)] · N              (N⁴ growth)

:class:`FlopTally` is the instrument: the innovation kernels in
:mod:`trackreplay.cores.array.angular_innovation` report every arithmetic step they execute with its real
operands, and the tally turns operand shapes and dtypes into FLOPs with the same convention
(a complex multiply-add costs 6 + 2 = 8, a real one 2, a real × complex product 2).
Linear solves are counted as the Gaussian elimination LAPACK performs (LU factorisation plus
one forward and one back substitution per right-hand side). Counts are per batch element,
i.e. per scan of one run, whatever batch the kernel ran on.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np

# cost of one multiplication / addition / division by operand kinds (complex?, complex?)
_MUL = {(False, False): 1, (False, True): 2, (True, False): 2, (True, True): 6}
_ADD = {(False, False): 1, (False, True): 1, (True, False): 1, (True, True): 2}
_COMPLEX_DIV = 11  # (a+jb)/(c+jd): c²+d² (3), ac+bd (3), bc−ad (3), two real divisions (2)


def proposed_flops(n_sensors: int, n_targets: int) -> int:
    """Paper's FLOP model of the closed-form innovation for all N targets of one scan."""
    M, N = int(n_sensors), int(n_targets)
    return 2 * (2 * N) ** 3 + 16 * M * N**2 + 8 * M**2 * N + (16 * M**2 + 8 * M) * N


def ryu_flops(n_sensors: int, n_targets: int) -> int:
    """Paper's FLOP model of Ryu's (2N+1)-dimensional least squares for all N targets."""
    M, N = int(n_sensors), int(n_targets)
    n = 2 * N + 1
    return (2 * n**3 + 8 * M * n**2 + 4 * M * n) * N


ANALYTIC = {"proposed": proposed_flops, "ryu": ryu_flops}


def _is_complex(a) -> bool:
    return np.iscomplexobj(a)


def gaussian_elimination_flops(n: int, n_rhs: int, complex_: bool) -> int:
    """Multiplications, additions and divisions of LU factorisation + substitutions.

    Factorisation: for each pivot k, (n−k) divisions and (n−k)² multiply-subtracts; each
    right-hand side: n(n−1)/2 multiply-subtracts forward, n(n−1)/2 backward and n divisions.
    """
    mul = _MUL[(complex_, complex_)]
    add = _ADD[(complex_, complex_)]
    div = _COMPLEX_DIV if complex_ else 1
    factor = sum((n - k) * div + (n - k) ** 2 * (mul + add) for k in range(1, n))
    subst = n * (n - 1) * (mul + add) + n * div
    return int(factor + n_rhs * subst)


class FlopTally:
    """Counts the FLOPs a kernel executes, per batch element, grouped by step label.

    The kernels call one method per arithmetic step, passing the operands they really used;
    leading (batch) axes are divided out through :meth:`batch`.
    """

    counting = True

    def __init__(self):
        self.by_step: dict[str, int] = defaultdict(int)
        self._batch = 1
        self._label = "other"

    def batch(self, shape) -> None:
        """Declare the batch shape of the kernel call (counts are divided by its size)."""
        self._batch = int(np.prod(shape)) if len(shape) else 1

    def step(self, label: str) -> None:
        """Attribute the following operations to ``label``."""
        self._label = label

    def _add(self, flops: float) -> None:
        self.by_step[self._label] += int(round(flops / self._batch))

    def matmul(self, a, b, out_shape) -> None:
        """``a @ b`` with inner dimension ``a.shape[-1]``; ``out_shape`` is the full result shape."""
        k = a.shape[-1]
        n_out = int(np.prod(out_shape))
        kinds = (_is_complex(a), _is_complex(b))
        self._add(n_out * (k * _MUL[kinds] + (k - 1) * _ADD[kinds]))

    def elementwise(self, op: str, a, b=None, out_shape=None) -> None:
        """One arithmetic operation per output element (``op``: mul, add, div)."""
        shape = out_shape if out_shape is not None else np.broadcast_shapes(np.shape(a), np.shape(b))
        n = int(np.prod(shape))
        kinds = (_is_complex(a), _is_complex(b) if b is not None else False)
        if op == "mul":
            cost = _MUL[kinds]
        elif op == "add":
            cost = _ADD[kinds]
        elif op == "div":
            cost = _COMPLEX_DIV if kinds[0] or kinds[1] else 1
        else:  # pragma: no cover - programming error
            raise ValueError(op)
        self._add(n * cost)

    def reduce_sum(self, a, axis_len: int) -> None:
        """Sum over an axis of length ``axis_len`` (``a`` is the input)."""
        n_out = int(np.prod(a.shape)) // axis_len
        self._add(n_out * (axis_len - 1) * _ADD[(_is_complex(a), _is_complex(a))])

    def solve(self, A, B) -> None:
        """``solve(A, B)`` for ``A`` (…, n, n) and ``B`` (…, n, r) or (…, n)."""
        n = A.shape[-1]
        n_rhs = B.shape[-1] if B.ndim == A.ndim else 1
        n_systems = int(np.prod(A.shape[:-2])) if A.ndim > 2 else 1
        self._add(n_systems * gaussian_elimination_flops(n, n_rhs, _is_complex(A) or _is_complex(B)))

    @property
    def total(self) -> int:
        return int(sum(self.by_step.values()))

class _NoTally:
    """The do-nothing instrument the kernels use when nobody counts."""

    counting = False

    def batch(self, shape):
        pass

    def step(self, label):
        pass

    def matmul(self, a, b, out_shape):
        pass

    def elementwise(self, op, a, b=None, out_shape=None):
        pass

    def reduce_sum(self, a, axis_len):
        pass

    def solve(self, A, B):
        pass


NO_TALLY = _NoTally()
