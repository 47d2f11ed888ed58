"""How far to trust a corner calibration: per-view residuals, the views it distrusts and why,
the board's fitted scale against its stated size, and a refusal when nothing fits.

:func:`diagnose_corner_calibration` takes what :func:`solutions.mle.calibrate_from_corners`
returned and the capture it came from, and gives a :class:`CalibrationDiagnosis` (typed values
a command line or a notebook prints; nothing to parse):

- every view's RMS corner error under the result (``fit_px``) and predicted by the same model
  fitted without that view (``held_out_px``): a view that only fits because it pulled the fit
  towards itself shows up in the second;
- a view is distrusted when its held-out error exceeds ``FLAG_RATIO`` times the median of the
  others'. Why 3: on the three real KUKA sequences the held-out p95 is 1.8-2.0 times the
  median for every sound method (docs/benchmarks/handeye_real.md), so a view three times the
  median is past what honest views of a real capture spread to;
- a board scale fitted more than ``SCALE_TOLERANCE`` (1 %) away from the stated size is
  reported with X refitted at the stated size, so the user sees both and the distance between
  them (a mis-measured board, or data that the scale bends to fit);
- a capture whose median view error stays above ``INCONSISTENT_FRACTION`` (2 %) of the image
  diagonal under the best model raises :class:`InconsistentCaptureError` with the diagnosis as
  its evidence: the poses and the images then disagree by far more than any noise (wrong pose
  convention, images out of order, a board moved during the capture).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from robots import geometry as geo
from solutions import mle

__all__ = [
    "FLAG_RATIO",
    "INCONSISTENT_FRACTION",
    "SCALE_TOLERANCE",
    "BoardScaleCheck",
    "CalibrationDiagnosis",
    "InconsistentCaptureError",
    "ViewResidual",
    "diagnose_corner_calibration",
]

FLAG_RATIO = 3.0
SCALE_TOLERANCE = 0.01
INCONSISTENT_FRACTION = 0.02


@dataclass(frozen=True)
class ViewResidual:
    """One view's corner error, pixels (RMS over its corners).

    ``fit_px``: under the calibration that used it; ``held_out_px``: predicted by the same model
    fitted on the other views (NaN if that fit failed); ``distrusted`` and ``why``: whether it
    disagrees with the rest beyond the noise, and the numbers that say so.
    """

    index: int
    fit_px: float
    held_out_px: float
    distrusted: bool
    why: str = ""


@dataclass(frozen=True)
class BoardScaleCheck:
    """The board's fitted scale against its stated size.

    ``scale``: fitted size / stated size. ``X_fitted``: the result's X (board at ``scale``);
    ``X_stated``: the same model refitted with the board at its stated size.
    ``shift_mm`` / ``turn_deg``: how far apart the two X are. ``held_out_px`` /
    ``stated_held_out_px``: the cross-validation score of the chosen model and of the same model
    at the stated size (NaN when not scored). ``off``: past ``SCALE_TOLERANCE``.
    """

    scale: float
    X_fitted: np.ndarray
    X_stated: np.ndarray
    shift_mm: float
    turn_deg: float
    held_out_px: float
    stated_held_out_px: float
    off: bool

    def message(self) -> str:
        """What the user is told when the scale is off, with X both ways."""
        fitted_mm = np.round(self.X_fitted[:3, 3] * 1000, 1)
        stated_mm = np.round(self.X_stated[:3, 3] * 1000, 1)
        return (f"the board was fitted at {self.scale:.3f} x its stated size "
                f"({100 * (self.scale - 1):+.1f} %): the board may be mis-measured, or the data "
                f"inconsistent. X with the fitted size: t = {fitted_mm.tolist()} mm; with the "
                f"stated size: t = {stated_mm.tolist()} mm ({self.shift_mm:.1f} mm and "
                f"{self.turn_deg:.2f} deg apart; held-out error {self.held_out_px:.2f} px "
                f"against {self.stated_held_out_px:.2f} px). Measure a printed square and "
                "calibrate with the true size.")


@dataclass(frozen=True)
class CalibrationDiagnosis:
    """What to trust in a corner calibration (see the module docstring).

    ``views``: one :class:`ViewResidual` per view, in capture order. ``median_held_out_px``:
    the median of their held-out errors. ``distrusted``: indices of the distrusted views.
    ``board_scale``: a :class:`BoardScaleCheck` when the chosen model fitted the board's
    scale, else None. ``warnings``: one sentence per thing the user must be told.
    ``consistent``: False when the median error is past ``INCONSISTENT_FRACTION`` of the
    image diagonal.
    """

    views: tuple[ViewResidual, ...]
    median_held_out_px: float
    distrusted: tuple[int, ...]
    board_scale: BoardScaleCheck | None
    warnings: tuple[str, ...]
    consistent: bool
    model: str = ""

    def table(self) -> list[tuple[int, float, float, str]]:
        """Rows (view, fit px, held-out px, "" or why it is distrusted) for printing."""
        return [(v.index, v.fit_px, v.held_out_px, v.why) for v in self.views]


class InconsistentCaptureError(ValueError):
    """The views cannot be made consistent; ``diagnosis`` holds the evidence."""

    def __init__(self, message: str, diagnosis: CalibrationDiagnosis):
        super().__init__(message)
        self.diagnosis = diagnosis


def _held_out(choice, P, px, K, dist, A, C, mount, start) -> np.ndarray:
    """Each view's RMS predicted by ``choice`` refitted on the other views: the project's one
    held-out error, ``mle.held_out_view_rms``, one view left out at a time.

    Unlike there, a refit that fails (ValueError: too few views left for the model) is not an
    error here but evidence: that view's entry is NaN, and ``_flag`` names the view as one the
    model cannot do without."""
    failed: list[np.ndarray] = []

    def refit(keep: np.ndarray):
        try:
            return mle.fit_candidate(choice, P, px[keep], K, dist, A[keep], C[keep], mount,
                                     start)
        except ValueError:
            failed.append(~keep)
            return start   # predicts something; the view is set to NaN below
    rms = mle.held_out_view_rms(refit, P, px, K, dist, A)
    for out in failed:
        rms[out] = np.nan
    return rms


def _flag(rms: np.ndarray) -> list[tuple[bool, str]]:
    out = []
    for i, value in enumerate(rms):
        others = np.delete(rms, i)
        typical = float(np.nanmedian(others)) if np.any(np.isfinite(others)) else np.nan
        if not np.isfinite(value):
            out.append((True, "the model could not be fitted without this view"))
        elif np.isfinite(typical) and value > FLAG_RATIO * typical:
            out.append((True, f"predicted from the other views it is off by {value:.2f} px, "
                              f"{value / typical:.1f} x the others' median {typical:.2f} px "
                              f"(limit {FLAG_RATIO:g} x): its robot pose, its image or its "
                              "corners disagree with the rest"))
        else:
            out.append((False, ""))
    return out


def _scale_check(result, choices, P, px, K, dist, A, C, mount) -> BoardScaleCheck | None:
    chosen = choices[0]
    if not chosen.fit_board_scale:
        return None
    stated = dataclasses.replace(chosen, fit_board_scale=False)
    X_stated = mle.fit_candidate(stated, P, px, K, dist, A, C, mount, result).X
    twin = [c for c in choices[1:] if c.method == chosen.method and not c.fit_board_scale
            and c.robot_weight == chosen.robot_weight and c.fit_intrinsics == chosen.fit_intrinsics]
    return BoardScaleCheck(
        scale=float(result.board_scale), X_fitted=result.X, X_stated=X_stated,
        shift_mm=float(geo.translation_error(result.X, X_stated)) * 1000,
        turn_deg=float(geo.rotation_error_deg(result.X, X_stated)),
        held_out_px=float(chosen.held_out_px),
        stated_held_out_px=float(twin[0].held_out_px) if twin else float("nan"),
        off=abs(result.board_scale - 1.0) > SCALE_TOLERANCE)


def diagnose_corner_calibration(result, choices, board_points, pixels, K, dist, base_T_flange,
                                mount: str = "eye_in_hand", image_size_wh=None, *,
                                refuse: bool = True) -> CalibrationDiagnosis:
    """Per-view residuals, distrusted views, the board's scale, and a refusal when nothing fits.

    ``result, choices``: what ``mle.calibrate_from_corners`` returned for this capture;
    ``board_points`` (N, 3) m, ``pixels`` (n, N, 2) px, ``K`` (3, 3), ``dist`` and
    ``base_T_flange`` (n, 4, 4) m: its inputs; ``mount`` as there. ``image_size_wh`` (width,
    height) px sets the consistency limit (default: twice the principal point).
    ``refuse=True`` raises :class:`InconsistentCaptureError` for an inconsistent capture;
    False returns the diagnosis with ``consistent=False``. Cost: the chosen model refitted once
    per view (the pose-based models take milliseconds, a corner fit up to a second).
    """
    if not choices or not isinstance(choices[0], mle.CornerNoiseChoice):
        raise ValueError("choices must be the list calibrate_from_corners returned with the "
                         "result (the chosen model first)")
    A = geo.as_poses(base_T_flange, "base_T_flange")
    P, px, K, dist = mle.check_corner_inputs(board_points, pixels, K, dist, len(A))
    C = mle.pnp_poses(P, px, K, dist)
    fit = mle.view_rms_px(mle.predicted_corners(result, P, K, dist, A), px)
    held = _held_out(choices[0], P, px, K, dist, A, C, mount, result)
    flags = _flag(held)
    views = tuple(ViewResidual(i, float(f), float(h), d, why)
                  for i, (f, h, (d, why)) in enumerate(zip(fit, held, flags)))
    distrusted = tuple(v.index for v in views if v.distrusted)
    scale = _scale_check(result, choices, P, px, K, dist, A, C, mount)
    warnings = [f"view {v.index}: {v.why}" for v in views if v.distrusted]
    if scale is not None and scale.off:
        warnings.append(scale.message())
    width, height = (image_size_wh if image_size_wh is not None
                     else (2 * K[0, 2], 2 * K[1, 2]))
    limit = INCONSISTENT_FRACTION * float(np.hypot(width, height))
    median_fit = float(np.median(fit))
    consistent = median_fit <= limit
    if not consistent:
        warnings.insert(0, f"the views cannot be made consistent: under the best model "
                           f"({choices[0].label}) the median view is off by {median_fit:.1f} px, "
                           f"past {100 * INCONSISTENT_FRACTION:g} % of the image diagonal "
                           f"({limit:.1f} px); check the pose convention (base_T_flange or its "
                           "inverse, units), that images and poses are in the same order, and "
                           "that the board did not move")
    diagnosis = CalibrationDiagnosis(
        views=views, median_held_out_px=float(np.nanmedian(held)) if np.any(np.isfinite(held))
        else float("nan"), distrusted=distrusted, board_scale=scale, warnings=tuple(warnings),
        consistent=consistent, model=choices[0].label)
    if refuse and not consistent:
        raise InconsistentCaptureError(warnings[0], diagnosis)
    return diagnosis
