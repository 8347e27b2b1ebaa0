"""Reading and scoring against the ground truth stored with synthetic demos (both styles).

Both generators store, per demo, the intended path at the demo's own timing (``truth_uv``) and
which samples are on the loops (``truth_on_loop``) as extra demo attrs. Two distances measure a
cleaned demo against them (issue 9, the README's "Cleaning quality"):

* :func:`shape_distance`: symmetric Chamfer distance between two paths, both densified to
  0.1 mm spacing by arc length first, so sample density (pauses, uneven rates) does not bias it
  (at 1 mm the nearest-point floor, ~0.25 mm, was the size of an expert-like demo's own noise);
* :func:`timing_distance`: the mean distance, sample by sample at the same times, to the
  intended path at the demo's own timing.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import KDTree

from bt_pipeline.data.loop_shape import arc_length_resample
from bt_pipeline.data.records import DemoRecord, FloatArray

_SPACING_M = 0.0001  # Densified paths: one point per 0.1 mm of arc length (module doc).


def truth_attrs(
    intended: ArrayLike, on_loop: ArrayLike, theta_deg: float, rho: float, cycles: float
) -> dict[str, object]:
    """The ground-truth demo attrs every generator stores (:data:`~bt_pipeline.data.synth_human.
    TRUTH_ATTRS`): the intended path (T, 2) [m] at the demo's own timing, which samples are on
    the loops (T,), the demonstrator's θ [deg] and ρ, and the loops drawn."""
    return {
        "truth_uv": np.asarray(intended).astype(np.float32),
        "truth_on_loop": np.asarray(on_loop).astype(np.uint8),
        "truth_theta_deg": theta_deg,
        "truth_rho": rho,
        "truth_cycles": cycles,
    }


def truth_of(record: DemoRecord) -> tuple[FloatArray, np.ndarray] | None:
    """The stored truth of a synthetic demo: (truth_uv (T, 2) [m], on_loop (T,) bool), or None."""
    if "truth_uv" not in record.attrs or "truth_on_loop" not in record.attrs:
        return None
    truth = np.asarray(record.attrs["truth_uv"], dtype=np.float64).reshape(-1, 2)
    on_loop = np.asarray(record.attrs["truth_on_loop"]).reshape(-1).astype(bool)
    return truth, on_loop


def densify(path: ArrayLike) -> FloatArray:
    """The polyline resampled by arc length at 0.1 mm spacing, shape (K, 2)."""
    x = np.asarray(path, dtype=np.float64)
    length = float(np.sum(np.linalg.norm(np.diff(x, axis=0), axis=1)))
    return arc_length_resample(x, max(16, int(length / _SPACING_M)))


def shape_distance(path: ArrayLike, truth: ArrayLike) -> float:
    """Symmetric Chamfer distance of two paths, both densified first [m]."""
    a, b = densify(path), densify(truth)
    return 0.5 * float(np.mean(KDTree(b).query(a)[0]) + np.mean(KDTree(a).query(b)[0]))


def timing_distance(path: ArrayLike, truth: ArrayLike) -> float:
    """Mean distance between two paths sampled at the same times, shape (T, 2) each [m]."""
    return float(np.mean(np.linalg.norm(np.asarray(path) - np.asarray(truth), axis=1)))


def truth_ratios(
    record: DemoRecord,
    raw: tuple[FloatArray, FloatArray],
    cleaned: tuple[FloatArray, FloatArray],
) -> tuple[float, float]:
    """After/before ratios of a cleaned synthetic demo against its stored truth: (shape, timing).

    Shape: :func:`shape_distance` of the cleaned output, then of the raw demo's true loop part,
    to the true loop part. Timing: :func:`timing_distance` to the truth at the cleaned output's
    (raw) sample times, of the output, then of the raw demo at the same times.

    Args:
        record: The raw synthetic demo (its ``truth_*`` attrs).
        raw: ``Demo.raw_samples()``: raw task-plane positions (T, 2) [m] and times (T,) [s].
        cleaned: ``TaskCleanResult.on_raw_times(i)``: the output's times (K,) [s] (raw times
            inside its span) and positions (K, 2) [m].
    """
    stored = truth_of(record)
    if stored is None:
        raise ValueError("the demo stores no ground truth (truth_uv, truth_on_loop)")
    return ratios_against(*stored, raw, cleaned)


def ratios_against(
    truth: FloatArray,
    on_loop: np.ndarray,
    raw: tuple[FloatArray, FloatArray],
    cleaned: tuple[FloatArray, FloatArray],
) -> tuple[float, float]:
    """:func:`truth_ratios` for a truth given as arrays: the intended path at each raw sample
    time, shape (T, 2) [m], and which raw samples are on the loops, shape (T,) bool."""
    (raw_uv, raw_t), (t, out) = raw, cleaned
    idx = np.searchsorted(raw_t, t)
    shape = shape_distance(out, truth[on_loop]) / shape_distance(raw_uv[on_loop], truth[on_loop])
    timing = timing_distance(out, truth[idx]) / timing_distance(raw_uv[idx], truth[idx])
    return shape, timing


def symmetry_turn(points: ArrayLike, tolerance: float = 0.005) -> float:
    """The smallest turn [deg] about its centroid that maps a closed loop onto itself (360°/n
    for the largest n in 2-8 that does: the turned points lie within `tolerance` of its size
    of the points on average; `points` dense along the loop), 360 for a loop with no such
    symmetry: a truth-side reading for :func:`relative_hits`."""
    p = np.asarray(points, dtype=np.float64)
    z = p[:, 0] + 1j * p[:, 1]
    z = z - z.mean()
    size = float(np.max(np.ptp(p, axis=0)))
    tree = KDTree(np.stack([z.real, z.imag], axis=1))
    for n in range(8, 1, -1):
        turned = z * np.exp(2j * np.pi / n)
        if np.mean(tree.query(np.stack([turned.real, turned.imag], axis=1))[0]) < tolerance * size:
            return 360.0 / n
    return 360.0


def oracle_similarity(
    positions: ArrayLike, intended: ArrayLike, on_loop: np.ndarray
) -> tuple[float, float]:
    """Rotation [deg] and scale, relative to the truth, of the least-squares similarity (free
    translation) that maps the intended path onto the drawn samples over the true loop part,
    sample for sample: the true correspondence, which no estimator has. A reference for θ/ρ
    estimates (``bench_guide_fits.py --oracle``, ``bench_operator_sets.py --oracle``); (0, 1)
    when the drawn loop is the intended one up to a translation."""
    x, want = np.asarray(positions, float)[on_loop], np.asarray(intended, float)[on_loop]
    drawn, meant = x[:, 0] + 1j * x[:, 1], want[:, 0] + 1j * want[:, 1]
    drawn, meant = drawn - drawn.mean(), meant - meant.mean()
    s = np.vdot(meant, drawn) / np.vdot(meant, meant)  # ρ'/ρ e^{i(θ'-θ)}
    return float(np.degrees(np.angle(s))), float(abs(s))


def relative_hits(
    thetas: ArrayLike,
    rhos: ArrayLike,
    true_thetas: ArrayLike,
    true_rhos: ArrayLike,
    period_deg: float = 360.0,
) -> np.ndarray:
    """Whether each demo's θ relative to the set's mean θ is within 5° of the truth's, and its ρ
    relative to the set's geometric-mean ρ within 5 %, shape (M,) (bool): what a loop learned
    from the demos can identify (its own frame is the set's). A loop that maps onto itself
    turned by `period_deg` (an n-fold symmetric loop: 360°/n) has θ only modulo that turn."""
    th, r = np.asarray(thetas, dtype=np.float64), np.asarray(rhos, dtype=np.float64)
    tt, tr = np.asarray(true_thetas, dtype=np.float64), np.asarray(true_rhos, dtype=np.float64)
    # θ − θ_true is the frame's turn plus each demo's error: the turn is their mean (circular,
    # modulo the symmetry turn, for a symmetric loop), the error what is left.
    off = th - tt
    frame = float(off.mean())
    if period_deg < 360.0:
        frame = float(np.angle(np.mean(np.exp(2j * np.pi * off / period_deg))))
        frame *= period_deg / (2 * np.pi)
    d_theta = (off - frame + period_deg / 2) % period_deg - period_deg / 2
    rel = (r / np.exp(np.log(r).mean())) / (tr / np.exp(np.log(tr).mean()))
    return (np.abs(d_theta) <= 5.0) & (np.abs(rel - 1.0) <= 0.05)
