"""Configurations chosen one at a time from a pool of candidates (a plan's design): the greedy choice,
Fedorov's exchange, and each candidate's gain kept up to date while the choice changes.

A candidate c is known by its information factor L_c (k x n: measuring it adds L_c^T L_c to the information
matrix). With C the covariance of the parameters, the task criterion is trace(C A) (A: the workspace's mean
G^T G, planning.py), and adding c lowers it by trace(S_c^-1 T_c), S_c = I + L_c C L_c^T, T_c = L_c C A C L_c^T
(Woodbury's identity); the D-optimal criterion (log det C) falls by log det S_c.

Computing S and T afresh for every candidate at each step costs two (N k x n) x (n x n) products and stacks of
small ones (16,000 Robonaut candidates: 10 ms, over a thousand times in a plan of 300). But every change of C is of
low rank, C' = C + W D W^T (W n x r: r the rows of the one candidate added or removed), and then, with
V_c = L_c W, P_c = L_c C A W and Q_c = V_c D,
    S_c' = S_c + Q_c V_c^T,    T_c' = T_c + H_c Q_c^T + Q_c H_c^T,    H_c = P_c + Q_c (W^T A W) / 2,
one (N k x n) x (n x 2r) product and sums over r per candidate. S and T are kept as (k, k, N) arrays (the
candidates last), so that those sums run over contiguous rows. Their rounding grows with how much C shrinks
(T's with its square: the first choices shrink a regularised C a millionfold along what they inform): adding c shrinks
it along L_c by up to the largest eigenvalue of S_c, and S and T are computed afresh once the product of those since
last time passes REFRESH_SHRINK, and every REFRESH_EVERY changes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

FIRST_LOOK = 64  # the best candidates ranked first; where none of them may be chosen, the next window is ranked,
WIDER = 16  # WIDER times as large (a stereo head's most informative candidates are often those the arm hides)
REFRESH_SHRINK = 1e3  # S and T afresh once C has shrunk this much since (module doc)
REFRESH_EVERY = 64  # and after this many changes at most


class Pool(Protocol):
    """What a selection chooses from: the planner's `Design`."""

    L: np.ndarray  # (N, k, n) each candidate's information factor (a pool may grow: more rows, never fewer)
    A: np.ndarray  # (n, n) the task criterion's weight: trace(C A)

    def start(self) -> np.ndarray:
        """The information before any candidate is chosen (n, n)."""
        ...

    def information(self, rows: np.ndarray) -> np.ndarray:
        """The information of candidates (indices) together (n, n)."""
        ...


class Selection:
    """Candidates chosen from a pool one at a time, with the covariance and every candidate's gain kept up
    to date (module doc)."""

    def __init__(
        self,
        pool: Pool,
        criterion: str = "task",
        chosen: Sequence[int] | None = None,
        admissible: Callable[[np.ndarray], int] | None = None,
    ) -> None:
        """`criterion`: "d" for D-optimal, else the task criterion trace(C A). `admissible`: the last check of
        candidates before one is chosen (the costly visibility check): given candidates (indices, best first), the
        position of the first that may be chosen, -1 if none may. Those it passes over are never offered again: a
        candidate it refuses once stays refused."""
        self.d = pool
        self.determinant = criterion == "d"
        self.admissible = admissible
        self.extra = np.zeros_like(pool.A)  # information of configurations outside the pool (measured frames)
        self.chosen: list[int] = []
        self._refused = np.zeros(len(pool.L), bool)
        self._factors: np.ndarray | None = None  # the pool's factors that self._L holds, candidates last
        self._refresh(inverse(pool.start()))
        for c in [] if chosen is None else chosen:
            self.add(int(c))

    def value(self, C: np.ndarray | None = None) -> float:
        """The criterion (smaller is better): trace(C A), or -log det M (D-optimal) as log det C."""
        C = self.C if C is None else C
        if self.determinant:
            return float(np.linalg.slogdet(C)[1])
        return float(np.trace(C @ self.d.A))

    def gains(self) -> np.ndarray:
        """How much adding each candidate lowers the criterion (N,)."""
        self._follow_pool()
        return self._gains(self._S, self._T)

    def add(self, c: int) -> None:
        self._follow_pool()
        self._change(*_woodbury(self.C, self.d.L[c], +1))
        self.chosen.append(c)

    def add_information(self, L: np.ndarray) -> None:
        """A configuration from outside the pool (a frame measured already): its information factor."""
        self._follow_pool()
        self._change(*_woodbury(self.C, L, +1))
        self.extra += L.T @ L

    def best(self) -> int:
        """The admissible candidate not chosen yet that lowers the criterion most (-1: none is left)."""
        return self._best(self.gains())

    def exchange(self, passes: int = 2, step: Callable[[int], None] | None = None) -> int:
        """Fedorov exchange: swap a chosen configuration for a candidate while the criterion falls.
        Returns the number of swaps. `step(k)`: called before the k-th (0-based, over all passes) chosen
        configuration is reconsidered."""
        self._follow_pool()
        swaps = 0
        for p in range(passes):
            improved = False
            for pos in range(len(self.chosen)):
                if step is not None:
                    step(p * len(self.chosen) + pos)
                L = self.d.L
                W, D = _woodbury(self.C, L[self.chosen[pos]], -1)
                C_without = _changed(self.C, W, D)
                S, T = self._moved(self.C, W, D)
                j = self._best(self._gains(S, T))
                if j < 0 or j == self.chosen[pos]:
                    continue
                before = self.value()
                W2, D2 = _woodbury(C_without, L[j], +1)
                C_with = _changed(C_without, W2, D2)
                if self.value(C_with) < before - 1e-9 * abs(before):
                    self._S, self._T, self.C = S, T, C_without
                    self._change(W2, D2)
                    self.chosen[pos] = j
                    swaps += 1
                    improved = True
            if not improved:
                break
        # Afresh: many up- and downdates of a nearly singular C (fewer configurations than parameters) drift.
        self._refresh(inverse(self.d.start() + self.d.information(np.array(self.chosen, int)) + self.extra))
        return swaps

    # --- the gains kept up to date -----------------------------------------------------------------------------

    def _refresh(self, C: np.ndarray) -> None:
        """C, and S and T computed afresh for every candidate of the pool."""
        self.C = C
        L = self.d.L
        N, k, n = L.shape
        if L is not self._factors:  # a copy, made again only when the pool has changed
            self._L = np.ascontiguousarray(L.transpose(2, 1, 0)).reshape(n, k * N)  # (n, k N): candidates last
            self._factors = L
        B = (C @ self._L).reshape(n, k, N)  # C L_c^T
        Lc = self._L.reshape(n, k, N)
        self._S = np.einsum("ikc,ilc->klc", B, Lc) + np.eye(k)[:, :, None]
        self._T = None
        if not self.determinant:
            w, U = np.linalg.eigh(self.d.A)
            E = ((U * np.sqrt(np.maximum(w, 0.0))).T @ B.reshape(n, -1)).reshape(n, k, N)  # A = R R^T, E = R^T B
            self._T = np.einsum("ikc,ilc->klc", E, E)
        self._shrink = 1.0
        self._changes = 0

    def _follow_pool(self) -> None:
        """Afresh when the pool has grown since (a plan's refinement adds candidates)."""
        if self.d.L is not self._factors:
            self._refused = np.concatenate([self._refused, np.zeros(len(self.d.L) - len(self._refused), bool)])
            self._refresh(self.C)

    def _change(self, W: np.ndarray, D: np.ndarray) -> None:
        """C + W D W^T for the selection: C, S and T."""
        self._S, self._T = self._moved(self.C, W, D)
        self.C = _changed(self.C, W, D)
        self._changes += 1
        self._shrink *= max(1.0, 1.0 / float(np.abs(np.linalg.eigvalsh(D)).min()))  # D = -(sign I + L C L^T)^-1
        if self._changes >= REFRESH_EVERY or self._shrink > REFRESH_SHRINK:
            self._refresh(self.C)

    def _moved(self, C: np.ndarray, W: np.ndarray, D: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """S and T at C + W D W^T from the selection's (at C), by the module doc's low-rank update."""
        k, N = self._S.shape[1:]
        r = W.shape[1]
        cols = W if self._T is None else np.hstack([W, C @ (self.d.A @ W)])
        Z = (cols.T @ self._L).reshape(-1, k, N)
        V = Z[:r]
        Q = (D @ V.reshape(r, -1)).reshape(V.shape)  # Q_c = V_c D (D symmetric)
        S = self._S + np.einsum("skc,slc->klc", Q, V)
        if self._T is None:
            return S, None
        G = W.T @ self.d.A @ W
        H = Z[r:] + 0.5 * (G @ Q.reshape(r, -1)).reshape(Q.shape)
        M = np.einsum("skc,slc->klc", H, Q)
        return S, self._T + M + M.transpose(1, 0, 2)

    def _gains(self, S: np.ndarray, T: np.ndarray | None) -> np.ndarray:
        if T is None:
            return np.linalg.slogdet(np.moveaxis(S, 2, 0))[1]
        return trace_solve(S, T)

    def _best(self, g: np.ndarray) -> int:
        """The admissible candidate of the largest gain g, not chosen yet (-1: none)."""
        g[self.chosen] = -np.inf
        g[self._refused] = -np.inf
        size, tried = FIRST_LOOK, 0
        while True:
            order = largest(g, size)[tried:]  # those not tried in the smaller window before
            order = order[np.isfinite(g[order])]
            at = (0 if len(order) else -1) if self.admissible is None else self.admissible(order)
            self._refused[order[: at if at >= 0 else len(order)]] = True
            if at >= 0:
                return int(order[at])
            if size >= len(g):
                return -1
            tried, size = size, size * WIDER


def largest(g: np.ndarray, size: int) -> np.ndarray:
    """The indices of the `size` largest values of g (NaN aside), largest first. A partial sort of all of g took as
    long as computing the gains (16,000 candidates: 0.2 ms, at every step): the largest value of each of 4 size blocks
    of g bounds them instead, since each of the `size` blocks of the largest such values holds one at least as large
    as the least of those, and only the values above that bound are sorted."""
    n = len(g)
    if size >= n:
        top = np.arange(n)
    else:
        width = n // (4 * size)
        peaks = g[: width * 4 * size].reshape(4 * size, width).max(axis=1) if width >= 8 else None
        bound = -np.inf if peaks is None else np.partition(peaks, len(peaks) - size)[len(peaks) - size]
        above = np.flatnonzero(g >= bound) if np.isfinite(bound) else None
        if above is not None and len(above) >= size:
            top = above[np.argpartition(-g[above], size - 1)[:size]]
        else:  # few blocks, or NaN or -inf among the largest of them: no bound
            top = np.argpartition(-g, size)[:size]
    return top[np.argsort(-g[top], kind="stable")]


def trace_solve(S: np.ndarray, T: np.ndarray) -> np.ndarray:
    """trace(S_c^-1 T_c) of each candidate c of (k, k, N) arrays (the candidates last), S_c symmetric positive
    definite, T_c symmetric. Up to 3 x 3 (a point's rows, Robonaut's 16,000 candidates) by the adjugate: a
    batched LAPACK solve of so small matrices costs more."""
    k = S.shape[0]
    if k == 1:
        return T[0, 0] / S[0, 0]
    if k == 2:
        return (S[1, 1] * T[0, 0] - 2.0 * S[0, 1] * T[0, 1] + S[0, 0] * T[1, 1]) / (S[0, 0] * S[1, 1] - S[0, 1] ** 2)
    if k == 3:
        s00, s01, s02, s11, s12, s22 = S[0, 0], S[0, 1], S[0, 2], S[1, 1], S[1, 2], S[2, 2]
        c00, c11, c22 = s11 * s22 - s12 * s12, s00 * s22 - s02 * s02, s00 * s11 - s01 * s01
        c01, c02, c12 = s02 * s12 - s01 * s22, s01 * s12 - s02 * s11, s01 * s02 - s00 * s12
        det = s00 * c00 + s01 * c01 + s02 * c02
        off = c01 * T[0, 1] + c02 * T[0, 2] + c12 * T[1, 2]
        return (c00 * T[0, 0] + c11 * T[1, 1] + c22 * T[2, 2] + 2.0 * off) / det
    return np.trace(np.linalg.solve(np.moveaxis(S, 2, 0), np.moveaxis(T, 2, 0)), axis1=1, axis2=2)


def _woodbury(C: np.ndarray, L: np.ndarray, sign: int) -> tuple[np.ndarray, np.ndarray]:
    """W and D of (C^-1 + sign L^T L)^-1 = C + W D W^T: adding (+1) or removing (-1) a configuration's
    information L (k x n)."""
    W = C @ L.T
    return W, -np.linalg.inv(sign * np.eye(len(L)) + L @ W)


def _changed(C: np.ndarray, W: np.ndarray, D: np.ndarray) -> np.ndarray:
    out = C + W @ D @ W.T
    return (out + out.T) / 2


def inverse(M: np.ndarray) -> np.ndarray:
    """M^-1, or its pseudo-inverse where M is singular."""
    try:
        return np.linalg.inv(M)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(M)
