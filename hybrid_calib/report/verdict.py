"""The report's verdict in words: is the vehicle's extrinsic within tolerance of its reference, does
it need recalibrating, or can the data not tell; and did the sensor move during the drive.

The result's drift block (``VehicleResult.drift``: ``calib.drift.DriftDecision.to_dict``) compares
the final estimate with the vehicle's reference (its calibration tables). When that block carries
its own ``"verdict"`` (words and tolerance, written by the calibrator) it is used as is, unless the
report is asked for another tolerance (``Tolerance``, ``--set tolerance.rot_deg=...``): its per-axis
test is then redone against that one (``calib.drift.against_tolerance``). Otherwise (a result
written before verdicts were stored) the verdict is derived here, per camera axis, from the change
``delta`` (``drift["delta_camera"]``) and the estimate's 1-sigma ``s`` (``final.std_cam``), against a
tolerance ``tol`` per axis (rotation deg, translation cm, ``ReportConfig``):

- "recalibrate": some axis changed by more than the tolerance beyond doubt, ``|delta| - 3 s > tol``;
- "within tolerance": every axis is within it beyond doubt, ``|delta| + 3 s <= tol``;
- "cannot tell": neither; the axes whose 3-sigma interval straddles the tolerance are named (a
  direction the data could not pin, e.g. the radar height of a 2D radar, ends here), as does a
  "degenerate" status, a last solve that did not converge ("NOT CONVERGED" in the status) or a
  result without drift block.

An ``inconclusive: ...`` status (the learned network's input was out of its domain: ``hybrid.ood``)
makes the verdict "cannot tell" with that reason before anything else, the drift block's own
verdict included: the estimate it tested cannot be trusted. One thing overrides every verdict: the
hybrid's radar mount monitor (``calib.mount_monitor``, independent of the network and the window)
measured the radar turning during the drive by more than the rotation tolerance beyond its 3 sigma:
"recalibrate", with that sentence first.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from hybrid_calib.calib.batch import fit_change_words
from hybrid_calib.calib.covariance import NOT_CONVERGED, status_kind
from hybrid_calib.calib.drift import (
    TOLERANCE_MAX,
    DriftConfig,
    against_tolerance,
    alarms_say_moved,
    doppler_level_words,
    mount_steps_beyond,
    one_pass_verdict,
    step_tests_ran,
    turned_since_export,
)
from hybrid_calib.calib.mount_monitor import (
    blind_words,
    change_words,
    finds_words,
    tested_words,
    told_steps,
    turn_words,
)
from hybrid_calib.calib.result import VehicleResult

DELTA_KEYS = ("rot_x_deg", "rot_y_deg", "rot_z_deg", "t_x_cm", "t_y_cm", "t_z_cm")
AXIS_NAMES = ("rotation about camera x", "rotation about camera y", "rotation about camera z",
              "translation along camera x", "translation along camera y", "translation along camera z")
VERDICTS = ("within tolerance", "recalibrate", "cannot tell")  # the calibrator's words (calib.drift.VERDICT_KINDS)
INCONCLUSIVE = "inconclusive"  # calib.covariance.inconclusive_status: the input is out of the network's domain


@dataclass(frozen=True)
class Tolerance:
    """The verdict's tolerance per camera axis. None (the default): the one the calibration's reference test used
    (``calib.drift.DriftConfig``: ``--set drift.tolerance_rot_deg=...`` at calibrate time); a value redoes that test
    against it (``calib.drift.against_tolerance``)."""

    rot_deg: float | None = None  # degrees per rotation axis: a change below this needs no recalibration
    trans_cm: float | None = None  # centimetres per translation axis

    def __post_init__(self):
        for name, unit in (("rot_deg", "degrees per rotation axis"), ("trans_cm", "centimetres per translation axis")):
            value = getattr(self, name)
            if value is None:
                continue
            top = TOLERANCE_MAX[name]  # the calibrator's bound (probe 40: 1e300 deg read "within tolerance")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or not 0 < value <= top:
                raise ValueError(f"{name} must be a finite number in (0, {top:g}] ({unit}), got {value!r}; e.g. --set "
                                 f"tolerance.{name}={_DEFAULT[name]:g} (the calibrator's default)")

    @property
    def given(self) -> bool:
        return self.rot_deg is not None or self.trans_cm is not None

    def resolved(self) -> Tolerance:
        """The tolerance with an unset axis at the calibrator's default (``DriftConfig``)."""
        return Tolerance(*(_DEFAULT[k] if getattr(self, k) is None else getattr(self, k) for k in _DEFAULT))

    def per_axis(self) -> np.ndarray:
        t = self.resolved()
        return np.array([t.rot_deg] * 3 + [t.trans_cm] * 3)

    def describe(self) -> str:
        t = self.resolved()
        return f"{t.rot_deg:g} deg per rotation axis, {t.trans_cm:g} cm per translation axis (camera axes)"


_DEFAULT = {"rot_deg": DriftConfig.tolerance_rot_deg, "trans_cm": DriftConfig.tolerance_trans_cm}


@dataclass(frozen=True)
class Verdict:
    """word: one of ``VERDICTS``; why: one or two sentences; tolerance: the tolerance in words;
    source: where the verdict came from; moved: whether the sensor stepped during the drive, in words;
    moved_frames: the frame indices of the step alarms; test: the reference test it read (the result's drift block,
    or that block redone against the tolerance asked for), None when it read none."""

    word: str
    why: str
    tolerance: str
    source: str
    moved: str
    moved_frames: tuple[int, ...] = ()
    test: dict | None = None

    @property
    def moved_answer(self) -> str:
        """The short answer ``moved`` opens with (``moved_during_drive`` writes each sentence so): "yes", "no",
        "not told" (no test could run) or "not tested" (a batch result)."""
        return next(a for a in MOVED_ANSWERS if self.moved.startswith(a))


def _fmt(j: int, v: float) -> str:
    return f"{v:.2f} deg" if j < 3 else f"{v:.1f} cm"


def derive_verdict(vr: VehicleResult, tol: Tolerance) -> tuple[str, str]:
    """(word, why) from the drift block, the std and the status (module docstring)."""
    if vr.final.status.startswith(INCONCLUSIVE):
        return "cannot tell", _out_of_domain_why(vr.final.status)
    if status_kind(vr.final.status) == "degenerate":
        return "cannot tell", f"The data could not determine the extrinsic ({vr.final.status})."
    if NOT_CONVERGED in vr.final.status:
        return "cannot tell", (f"The last solve did not converge, so its estimate says nothing about the mount "
                                f"({vr.final.status}).")
    d = vr.drift or {}
    if "delta_camera" not in d:
        return "cannot tell", "The result holds no comparison with a reference extrinsic (no drift block)."
    delta = np.array([float(d["delta_camera"][k]) for k in DELTA_KEYS])
    s, t = np.asarray(vr.final.std, float), tol.per_axis()
    out = np.abs(delta) - 3 * s > t
    inside = np.abs(delta) + 3 * s <= t
    if out.any():
        axes = "; ".join(f"{AXIS_NAMES[j]} changed by {_fmt(j, delta[j])} (+- {_fmt(j, 3 * s[j])} at 3 sigma)"
                         for j in np.flatnonzero(out))
        return "recalibrate", f"The extrinsic moved from its reference beyond the tolerance: {axes}."
    if inside.all():
        return "within tolerance", ("Every axis differs from the reference by less than the tolerance, with its "
                                    "3-sigma interval inside it.")
    axes = "; ".join(f"{AXIS_NAMES[j]}: {_fmt(j, delta[j])} +- {_fmt(j, 3 * s[j])} (3 sigma)"
                     for j in np.flatnonzero(~inside))
    return "cannot tell", (f"The data cannot tell whether these axes are within the tolerance of the reference "
                            f"(their 3-sigma interval straddles it): {axes}.")


def _out_of_domain_why(status: str) -> str:
    reason = status[len(INCONCLUSIVE):].lstrip(": ")
    return f"The result cannot be trusted, so it says nothing about the mount: {reason}."


MOVED_ANSWERS = ("yes", "not told", "not tested", "no")  # the words a moved sentence opens with ("no" last)


def alarm_words(vr: VehicleResult) -> list[str]:
    """Per step alarm of ``vr``'s trajectory, in drive order: "frame K: " and which test raised it. A radar mount
    monitor step (``vr.mount["steps"]``) is credited to the first alarm at or after its ``at``; the others are the
    window's own step test. A monitor alarm at frame 13 read "the window's step test ... the window restarted
    there", where the window had kept the frames from the change at frame 8 (probe 30)."""
    alarms = [f.index for f in vr.trajectory if f.step_alarm]
    credited: dict[int, dict] = {}
    for st in sorted(told_steps(vr.mount), key=lambda st: int(st.get("at", 0))):
        a = next((a for a in alarms if a >= int(st.get("at", 0)) and a not in credited), None)
        if a is not None:
            credited[a] = st
    out = []
    # the window's test on an untrusted estimate (out of domain, no view, ...): its inputs may have jumped, not the
    # mount (probe 34: a rear radar with the front camera read "the mount changed inside the drive" at frame 15)
    untrusted = status_kind(vr.final.status) == "inconclusive"
    # what may have jumped: the oracle runs no network (probe 41: its alarm read "the network's outputs")
    inputs = "its correspondence rows" if vr.method == "oracle" else "the network's outputs"
    for a in alarms:
        st = credited.get(a)
        out.append(f"frame {a}: the window's step test, on an estimate that is not trusted (its status is "
                   f"inconclusive: {inputs} may have jumped, not the mount; the window restarted there)"
                   if st is None and untrusted else
                   f"frame {a}: the window's step test (the mount changed inside the drive; the window restarted "
                   "there, the estimate is the mount after it)" if st is None else
                   f"frame {a}: the radar mount monitor (its Doppler against the ego poses): the radar turned by "
                   f"{turn_words(st['step_deg'], st['std_deg'])} {change_words(st)}; the window kept "
                   "only the frames since then"
                   # raised on a frame that was not fused (probe 39: "step alarm at frame 14" beside the monitor's
                   # "(alarm at frame 13)" for one alarm: frame 13 was dropped out of the network's domain)
                   + ("" if int(st.get("at", a)) == a else f" (raised at frame {st['at']}, applied at frame {a}, the "
                                                             "next one fused)"))
    return out


def moved_during_drive(vr: VehicleResult) -> tuple[str, tuple[int, ...]]:
    """Whether a step test fired (the window's, and the hybrid's radar mount monitor), in words opening with
    one of ``MOVED_ANSWERS``, and the frames where it did. "no" only when a test ran: the pure methods run no
    window and a short drive gives its test no statistic, which read "no: no step alarm" (probe 30)."""
    if not vr.trajectory:
        change = (vr.drift or {}).get("fit_change")
        if isinstance(change, dict) and {"frame", "before", "after", "z"} <= set(change):  # calib.batch.fit_change
            return ("not told: a batch result runs no step test (the step detector runs in the sliding window only), "
                    f"but {fit_change_words(change)}"), ()
        return "not tested (batch result: the step detector runs in the sliding window only)", ()
    alarms = tuple(f.index for f in vr.trajectory if f.step_alarm)
    mount = vr.mount or {}
    n = len(vr.trajectory)
    window_ran, mount_ran = step_tests_ran(vr.trajectory, mount)
    first = next((f.index for f in vr.trajectory if f.step_statistic is not None), None)
    # the frames before its first statistic build the long-run estimate it tests against: a step there is in it
    # (probe 129: radars knocked at frame 6 read "Did the sensor move? no", nothing said of the first frames)
    window = (f"the window's windowed chi-square of the recent frames against the long-run estimate, over the {n} "
              "frames the estimate used" + (f", blind to a step before frame {first} (the frames its long-run "
                                            "estimate is first built from)" if first and first > vr.trajectory[0].index
                                            else "")) if window_ran else ""
    blind = blind_words(mount) if mount else ""
    monitor = (f"the radar mount monitor (the radar's Doppler heading against the vehicle's ego poses) over "
               f"{tested_words(mount, (vr.drift or {}).get('reference'))}") if mount else ""
    if alarms and not alarms_say_moved(vr.final.status, mount):
        return "not told: step alarm at " + "; ".join(alarm_words(vr)), alarms
    if alarms:
        return "yes: the sensor stepped during the drive; step alarm at " + "; ".join(alarm_words(vr)), alarms
    if mount.get("implausible"):
        return f"not told for the radar's yaw: {mount['implausible']}" + (
            f"; no step alarm from {window}" if window else ""), ()
    if not window_ran and not mount_ran:
        why = (f"the window's step test computed no statistic over these {n} frames (a drive too short for its "
               "history, or a method that runs no window: pure, pure-avg)")
        return f"not tested: no step test could run on this result ({why}" + (
            f"; the radar mount monitor: {blind or tested_words(mount, (vr.drift or {}).get('reference'))}"
            if mount else "") + ")", ()
    if mount and not mount_ran:  # the window's test ran; the monitor tested nothing, or too little to alarm
        return (f"not told for the radar's yaw: {monitor}" + (f"; {blind}" if blind.startswith("it could not") else "")
                + f"; no step alarm from {window}"), ()
    tests = " and from ".join(t for t in (monitor, window) if t)  # a monitor here ran (the branch above)
    finds = finds_words(mount) if mount_ran else ""
    # the monitor sees turns in yaw alone: with no window test beside it, a shift of the radar without a turn is looked
    # for by nothing (probe 123: a radar moved 20 cm sideways mid-drive read "Did the sensor move? no")
    unseen = ("; a shift of the radar without a turn in yaw, or a turn in roll or pitch alone, is looked for by no "
              "test here (the window's step test ran on no rows)") if mount_ran and not window_ran else ""
    return (f"no: no step alarm from {tests}" + (f"; the radar mount monitor is {blind}" if blind.startswith("blind")
                                                else "") + (f"; by the monitor {finds}" if finds else "") + unseen), ()


def verdict_of(vr: VehicleResult, tol: Tolerance | None = None) -> Verdict:
    """The vehicle's verdict: the drift block's own ``"verdict"`` when present, else ``derive_verdict``;
    "recalibrate" whatever they say when the radar mount monitor measured a step beyond the rotation
    tolerance during the drive (``calib.drift.mount_steps_beyond``: it rests on neither the network nor the window)."""
    tol = tol or Tolerance()
    if (vr.drift or {}).get("at_end"):  # the calibrator's own verdict raised by a step (calib.drift.with_mount_step):
        vr = dataclasses.replace(vr, drift={**vr.drift, **vr.drift["at_end"]})  # judged here against ``tol`` again
    v = _verdict_vs_reference(vr, tol)
    stored = ((vr.drift or {}).get("axes") or {}).get("yaw") or {}  # the calibration's own, when none is asked for
    rot = tol.rot_deg if tol.rot_deg is not None else float(stored.get("tolerance", tol.resolved().rot_deg))
    turned = mount_steps_beyond(vr.mount, rot) or turned_since_export(vr.drift, vr.mount, rot)
    if not turned:
        return v
    # the why often opens with its own verdict words ("cannot tell: ..."): said once, not "inconclusive: cannot tell"
    said = v.why if v.why.startswith(("cannot tell", "within tolerance", "differs", "inconclusive")) else \
        f"{v.word}: {v.why}"
    return Verdict("recalibrate", f"{turned} Against the reference at the drive's end: {said}",
                   v.tolerance, f"the radar mount monitor; {v.source}", v.moved, v.moved_frames)


def _verdict_vs_reference(vr: VehicleResult, tol: Tolerance) -> Verdict:
    moved, frames = moved_during_drive(vr)
    if frames and NOT_CONVERGED in vr.final.status:
        moved += "; but the solve did not converge, so these alarms may only mark its failures"
    d = vr.drift or {}
    if vr.final.status.startswith(INCONCLUSIVE):  # the radar's own Doppler level, as calibrate says it (probe 36)
        level = doppler_level_words(d)
        return Verdict("cannot tell", _out_of_domain_why(vr.final.status) + (f"; {level}" if level else ""),
                       tol.describe(), "the result's status (not trusted)", moved, frames)
    source = "the calibrator's reference test (result.json drift block)"
    if d.get("verdict_kind") and tol.given:  # the tolerance asked for: the calibrator's per-axis test redone with it
        redone = against_tolerance(d, vr.final.status, vr.mount, tol.rot_deg, tol.trans_cm)
        if vr.method == "pure":  # one pass decides nothing, against any tolerance (probe 113: it read "recalibrate")
            redone = one_pass_verdict(redone)
        if redone is not d:
            d, source = redone, f"{source}, redone against the tolerance asked for"
    given = d.get("verdict")
    kind = d.get("verdict_kind")
    if kind:  # the calibrator's reference test (calib.drift): kind, sentence and per-axis tolerances
        word = kind
        tols = {a.get("unit"): a.get("tolerance") for a in (d.get("axes") or {}).values()}
        # in Tolerance.describe's words (probe 126: a fleet page said the one or the other by its first vehicle)
        kinds = {"deg": "rotation", "cm": "translation"}
        tol_text = ", ".join(f"{v:g} {u} per {kinds.get(str(u), 'camera')} axis" for u, v in tols.items()
                             if v is not None)
        tol_text = f"{tol_text} (camera axes)" if tol_text else ""
        return Verdict(word, str(given or kind), tol_text or "not stated by the result", source, moved, frames, d)
    if given:
        word = given.get("verdict", given.get("word", "")) if isinstance(given, dict) else str(given)
        why = (given.get("why") or given.get("reason") or "") if isinstance(given, dict) else ""
        why = why or d.get("why") or d.get("reason") or ""
        tol_given = d.get("tolerance", given.get("tolerance") if isinstance(given, dict) else None)
        if isinstance(tol_given, dict):
            tol_given = ", ".join(f"{k} {v:g}" if isinstance(v, (int, float)) else f"{k} {v}"
                                  for k, v in tol_given.items())
        return Verdict(word, why, str(tol_given) if tol_given is not None else "not stated by the result",
                       "the calibrator's verdict (result.json drift block)", moved, frames)
    word, why = derive_verdict(vr, tol)
    return Verdict(word, why, tol.describe(), "derived by the report from the change against the reference and "
                   "its 1-sigma", moved, frames)
