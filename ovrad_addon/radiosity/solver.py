"""Solving (C - R) B = C E by progressive shooting, and a direct reference solve for small scenes.

Shooting works in test space: the light that shooters K send lands as EC = R[:, K] dB_K in
the test regions D_h, and C dB = EC turns it back into basis coefficients. The fixed point is
B = E + C^-1 R B, i.e. exactly the paper's equation (9). The paper's published distribution
rule (dB_i = c_ih EC_h / (A_h A_i)) is kept as rule="paper" for comparison: its fixed point is
B = E + P R B with P = diag(1/A) C^T diag(1/A), which is not (9) (see docs/method.md).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csc_matrix, diags
from scipy.sparse.linalg import LinearOperator, SuperLU, gmres, splu

from ..errors import OvradError

# Each shooting step shoots the patches holding this share of the unshot power. Measured on the
# Cornell box with 100 652 patches (G 99 M entries): to 1e-3 unshot, 64 patches per step took
# 5 800 steps and 258 s; shares 0.5 / 0.9 / 0.99 took 24 / 12 / 11 steps and 10 / 5.4 / 4.9 s,
# all patches with any unshot power 11 steps and 4.4 s, every one reaching the same radiosity
# within 3e-5 of its largest value.
SHOOT_SHARE = 0.99

# Relative diagonal shift that keeps C factorable when patches coincide (C singular): it picks
# a small-norm split of B between coincident patches; the reconstructed B is unaffected.
_DIAGONAL_SHIFT = 1e-9


@dataclass
class SolveState:
    """Where a solve stands; can be continued by passing it back.

    radiosity (n, 3) B per patch, unshot (n, 3) dB not yet shot, shots taken, rays cast,
    elapsed seconds, converged flag, history of (shots, unshot fraction).
    """

    radiosity: np.ndarray
    unshot: np.ndarray
    shots: int = 0
    rays: int = 0
    elapsed: float = 0.0
    converged: bool = False
    history: list = field(default_factory=list)
    method: str = "shooting"
    # The first shot's share of radiosity (n, 3): the direct light of lamps and sampled emitters
    # as the patches hold it; bake points replace it by direct light computed where they are.
    first_shot: np.ndarray | None = None


@dataclass(frozen=True)
class SolveProgress:
    """What a solve reports after each step: fraction done (0..1), unshot power over the reference,
    elapsed seconds, rays cast so far, and the state itself (read it, e.g. to show the current
    radiosity; it is updated in place as the solve goes on)."""

    fraction: float
    unshot: float
    elapsed: float
    rays: int
    state: SolveState


# Called after each shooting step; returning False cancels the solve.
Progress = Callable[[SolveProgress], bool] | None


def diagonal_shift(diagonal: np.ndarray) -> np.ndarray:
    """The tiny shift (n,) added to C's diagonal before solving with it (see _DIAGONAL_SHIFT)."""
    d = np.abs(diagonal)
    return _DIAGONAL_SHIFT * np.maximum(d, d.max() * 1e-12)


def factorize(C) -> SuperLU:
    """Sparse LU of C (n x n) with its diagonal shifted a hair (diagonal_shift), so that it
    factors even when patches coincide; .solve(rhs) then applies C^-1."""
    Cc = csc_matrix(C, dtype=np.float64)
    return splu((Cc + diags(diagonal_shift(Cc.diagonal()))).tocsc())


def inverse_areas(A: np.ndarray) -> np.ndarray:
    """1 / A_h, and 0 for a patch with no support (nothing of the surface in it: it neither
    receives nor holds light, and must not turn the paper's rule into NaN)."""
    A = np.asarray(A, np.float64)
    out = np.zeros_like(A)
    np.divide(1.0, A, out=out, where=A > 0)
    return out


def unshot_fraction(effective_area: np.ndarray, unshot: np.ndarray, emitted: float) -> float:
    """Unshot power sum_k c_kk |dB_k| (all channels) over the emitted power."""
    return float(np.sum(effective_area[:, None] * np.abs(unshot)) / max(emitted, 1e-300))


def solve_progressive(
    C,
    transport,
    emission: np.ndarray,
    tolerance: float = 1e-3,
    batch: int | None = None,
    rule: str = "exact",
    support_area: np.ndarray | None = None,
    progress: Progress = None,
    state: SolveState | None = None,
    max_shots: int = 100_000_000,
    reference_power: float | None = None,
    share: float = SHOOT_SHARE,
    lu: SuperLU | None = None,
) -> SolveState:
    """Shoot the largest unshot power first until unshot < tolerance.

    Each step shoots the patches that hold `share` of the unshot power, largest first, and at
    least `batch` of them (all that hold any, if fewer). One step costs a product with G and a
    solve with C's factors whatever it shoots, so shooting a fixed few per step made the solve
    grow with the patch count squared (see SHOOT_SHARE).
    C (n x n sparse), transport (R, see radiosity/transport.py), emission E (n, 3) per
    patch exitance; lu: C's factors (factorize(C)), when the caller has them already.
    progress(SolveProgress) returning False cancels: the state returned is then the last
    consistent one (every state is a valid radiosity).
    reference_power: what unshot power is measured against (default: the emitted power).
    """
    if rule not in ("exact", "paper"):
        raise OvradError(f"solver rule must be 'exact' or 'paper', got {rule!r}")
    E = np.asarray(emission, np.float64).reshape(-1, 3)
    n = len(E)
    ckk = np.asarray(C.diagonal(), np.float64)
    emitted = float(np.sum(ckk[:, None] * np.abs(E))) if reference_power is None else reference_power
    if emitted <= 0:
        raise OvradError("no light: nothing in the scene emits (add an emissive material or a lamp)")
    if not 0.0 < share <= 1.0:
        raise OvradError(f"share must be in (0, 1], got {share}")
    if rule == "exact":
        lu = lu if lu is not None else factorize(C)
        to_basis = lu.solve
    else:
        A = np.asarray(support_area if support_area is not None else np.asarray(C.sum(axis=1)).ravel())
        P = diags(inverse_areas(A)) @ csc_matrix(C).T @ diags(inverse_areas(A))
        to_basis = P.dot
    st = state or SolveState(radiosity=E.copy(), unshot=E.copy())
    best = np.inf
    batch = batch or max(1, min(n, 64))
    t0 = time.perf_counter() - st.elapsed
    start_frac = unshot_fraction(ckk, st.unshot, emitted)
    while st.shots < max_shots:
        frac = unshot_fraction(ckk, st.unshot, emitted)
        st.history.append((st.shots, frac))
        if frac < tolerance:
            st.converged = True
            break
        best = min(best, frac)
        if rule == "exact" and (not np.isfinite(frac) or (frac > 10.0 * best and st.shots > n)):
            # Shooting order can amplify when C is badly conditioned (large smooth overlaps,
            # rho near 1). Krylov iterations on the same equation (9) finish the job.
            st.radiosity = _krylov(lu, transport, st.radiosity, st.unshot, tolerance)
            st.unshot = np.zeros_like(E)
            st.method = "shooting+gmres"
            continue
        K = shooters(ckk * np.abs(st.unshot).sum(axis=1), share, batch)
        received = transport.received(K, st.unshot[K])
        dB = to_basis(received)
        st.radiosity = st.radiosity + dB
        unshot = st.unshot.copy()
        unshot[K] = 0.0
        st.unshot = unshot + dB
        st.shots += len(K)
        st.elapsed = time.perf_counter() - t0
        if progress is not None:
            done = 1.0 - np.log(max(frac, tolerance) / tolerance) / max(np.log(start_frac / tolerance), 1e-12)
            report = SolveProgress(float(np.clip(done, 0, 1)), frac, st.elapsed, st.rays, st)
            if progress(report) is False:
                break
    return st


def shooters(power: np.ndarray, share: float, batch: int) -> np.ndarray:
    """The patches to shoot: largest power first, until they hold `share` of the power, and at
    least `batch` of them; never a patch with no power."""
    total = float(power.sum())
    if total <= 0:
        return np.zeros(0, np.int64)
    order = np.argsort(-power, kind="stable")
    held = np.cumsum(power[order])
    k = max(int(np.searchsorted(held, share * total)) + 1, batch)
    K = order[: min(k, len(order))]
    return K[power[K] > 0]


def _krylov(lu, transport, radiosity, unshot, tolerance):
    """Finish a solve with GMRES: the remaining X = (I - G)^-1 G U, G = C^-1 R, U the unshot.

    Shooting keeps B_final = B + (I - G)^-1 G U invariant, so this is exact for any state.
    """
    n = len(unshot)
    rhs = lu.solve(transport.apply(unshot))
    out = []
    for j in range(3):

        def apply(x, j=j):
            full = np.zeros((n, 3))
            full[:, j] = x
            return x - lu.solve(transport.apply(full))[:, j]

        op = LinearOperator((n, n), matvec=apply, dtype=np.float64)
        scale = max(float(np.abs(radiosity[:, j]).max()), 1e-300)
        x, info = gmres(op, rhs[:, j], rtol=0.0, atol=tolerance * 1e-2 * scale, restart=60, maxiter=500)
        if info != 0:
            raise OvradError("the solve did not converge: reduce the overlap or use the box profile")
        out.append(x)
    return radiosity + np.column_stack(out)


def solve_direct(C, transport, emission: np.ndarray) -> np.ndarray:
    """Reference: (C - R) B = C E solved directly with dense matrices (small scenes and tests)."""
    E = np.asarray(emission, np.float64).reshape(-1, 3)
    Cd = csc_matrix(C).toarray()
    Cd += np.diag(diagonal_shift(np.diag(Cd)))
    out = []
    G = transport.matrix().toarray()
    for j in range(3):
        R = transport.rho[:, [j]] * G
        out.append(np.linalg.solve(Cd - R, csc_matrix(C) @ E[:, j]))
    return np.column_stack(out)


__all__ = [
    "Progress",
    "SolveProgress",
    "SolveState",
    "shooters",
    "solve_direct",
    "solve_progressive",
    "unshot_fraction",
]
