"""Sparse symmetric positive definite systems: CSR matrices and conjugate gradients.

``cg`` solves A x = rhs by Jacobi-preconditioned conjugate gradients, in the compiled kernel
(``seam_csr_cg``, aobake/_sparse.c, on threads splitting the rows) or in numpy with the
same operations in the same order (``cg_numpy``): the same bits either way, and for any
number of threads (tests/test_seams.py).  The seam erasure (``aobake.targets.texels.seams``)
assembles its normal matrix and solves it here.

The numpy arithmetic is written so that the compiled kernel can repeat it operation for
operation: element-wise steps, and every sum in a fixed order (a row's sum in column order
from 0.0; a dot product is a cumsum), never einsum or BLAS, whose order of summation
depends on the CPU.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Csr(NamedTuple):
    """A square sparse matrix in compressed sparse rows: indptr (n + 1,) int64, indices
    (nnz,) int32 ascending in each row, data (nnz,) float64.  ``cg`` needs every diagonal
    stored."""

    indptr: np.ndarray
    indices: np.ndarray
    data: np.ndarray

    def diagonal(self) -> np.ndarray:
        """(n,) float64 the stored diagonal (every row must hold its own)."""
        rows = np.repeat(np.arange(len(self.indptr) - 1), np.diff(self.indptr))
        return np.ascontiguousarray(self.data[rows == self.indices])


def cg(matrix: Csr, diag: np.ndarray, rhs: np.ndarray, x0: np.ndarray, tolerance: float,
       max_iterations: int, kernels=None, threads: int = 1) -> tuple[np.ndarray, int, float]:
    """Jacobi-preconditioned conjugate gradients on A x = rhs from x = x0, until
    max |r / diag| <= tolerance or max_iterations.

    matrix : Csr (n x n, symmetric positive definite, every diagonal stored), diag : (n,)
    float64 its diagonal (``matrix.diagonal()``), rhs, x0 : (n,) float64.  kernels : the
    compiled module (``aobake._native.kernels()``; its ``seam_csr_cg`` on ``threads``
    threads) or None (``cg_numpy``); the same bits either way.  Returns (x (n,) float64,
    iterations, the last max |r / diag|).
    """
    if kernels is None:
        return cg_numpy(matrix, diag, rhs, x0, tolerance, max_iterations)
    x = np.empty_like(x0)
    iterations, left = kernels.seam_csr_cg(matrix.indptr, matrix.indices, matrix.data, diag,
                                           rhs, x0, x, float(tolerance), int(max_iterations),
                                           int(threads))
    return x, iterations, left


def cg_numpy(matrix: Csr, diag, rhs, x0, tolerance, max_iterations
             ) -> tuple[np.ndarray, int, float]:
    """``cg`` in numpy, the reference: (x (n,), iterations, the last max |r / diag|)."""
    ranks = ranks_of(matrix)
    x = x0.copy()
    r = rhs - apply(matrix, x, ranks)
    z = r / diag
    p = z.copy()
    rz = _dot(r, z)
    it = 0
    while np.max(np.abs(z), initial=0.0) > tolerance and it < max_iterations:
        q = apply(matrix, p, ranks)
        alpha = rz / _dot(p, q)
        x += alpha * p
        r -= alpha * q
        z = r / diag
        rz, rz_old = _dot(r, z), rz
        p = z + (rz / rz_old) * p
        it += 1
    return x, it, float(np.max(np.abs(z), initial=0.0))


def apply(matrix: Csr, x: np.ndarray, ranks: list) -> np.ndarray:
    """(n,) A x, each row summed in column order from 0.0 (the kernel's order): ``ranks``
    from ``ranks_of``."""
    out = np.zeros(len(matrix.indptr) - 1)
    for rows, at in ranks:
        out[rows] += matrix.data[at] * x[matrix.indices[at]]
    return out


def ranks_of(matrix: Csr) -> list:
    """Per rank r, (the rows with more than r entries, the position of their r-th)."""
    length = np.diff(matrix.indptr)
    out = []
    for r in range(int(length.max(initial=0))):
        rows = np.nonzero(length > r)[0]
        out.append((rows, matrix.indptr[rows] + r))
    return out


def _dot(a: np.ndarray, b: np.ndarray) -> float:
    """a . b summed in index order (the kernel's order)."""
    return float(np.cumsum(a * b)[-1]) if len(a) else 0.0
