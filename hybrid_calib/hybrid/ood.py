"""What the learned methods do with the network's out-of-domain score (``learned.ood``).

Rule (``OODPolicy``; every learned method, ``hybrid.loop``):

1. A frame whose score exceeds ``threshold`` (1: less typical than 99 % of held-out in-domain
   frames) is out of domain: it is DROPPED (no estimate, no rows, no prior from it) and recorded
   in the result's ``frames_skipped`` with the reason and its score.
2. A vehicle is ``inconclusive`` when fewer than ``min_in_domain_frames`` frames, or less than
   ``min_in_domain_fraction`` of its frames, are in domain, and the status is ``inconclusive: <reason in
   words>`` (``calib.covariance.inconclusive_status``): never ``ok``. Its estimate still keeps to the frames in
   domain when there are at least ``min_in_domain_frames`` of them (``inconclusive_frames`` "in-domain"); with
   fewer, the method runs on all its frames (nothing dropped, so there is an estimate to look at). Probe 44: an
   unchanged randomised highway drive, 44 of 60 frames in domain, run on every frame: a stretch of out-of-domain
   frames (the vehicle crawling at 1-1.6 m/s) raised a false step alarm, and the drive ended 3.2 deg off in yaw
   with NEES 41; on its in-domain frames it ends 0.37 deg off, NEES 6.8.
3. A checkpoint without ``export.ood`` (fitted before the score existed) keeps working: nothing is
   dropped, and the result's ``ood`` block says the score is unavailable and how to fit it.

The scores of every frame, the decision and its reason are the result's ``ood`` block
(``VehicleResult.ood``). ``ood_passes`` runs the network over a drive's frames from starts drawn in a
range (optionally corrupted: ``CORRUPTIONS``); ``benchmarks/ood_fit.py`` fits and measures the score
with it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

CORRUPTIONS = ("noise-image", "shuffled-radar", "blank-depth")


@dataclass(frozen=True)
class OODPolicy:
    enabled: bool = True  # use the checkpoint's export.ood (when it has one)
    threshold: float = 1.0  # score above this: the frame is out of domain (dropped)
    min_in_domain_fraction: float = 0.8  # fewer in-domain frames than this fraction: inconclusive
    min_in_domain_frames: int = 3  # fewer in-domain frames than this: inconclusive
    # an inconclusive vehicle's estimate: "in-domain" = of its in-domain frames while at least min_in_domain_frames
    # are (every frame with fewer) | "all" = of every frame (module doc, rule 2)
    inconclusive_frames: str = "in-domain"

    def __post_init__(self):
        from hybrid_calib.config import require_ranges

        if self.inconclusive_frames not in ("in-domain", "all"):
            raise ValueError(f"OODPolicy.inconclusive_frames={self.inconclusive_frames!r}; valid: in-domain, all")

        require_ranges(self, {"threshold": "(0, 1e6]", "min_in_domain_fraction": "[0, 1]",
                              "min_in_domain_frames": "[0, 1e9]"})


def json_score(score: float) -> float | None:
    """A score for JSON: None when unavailable (NaN)."""
    return float(score) if np.isfinite(score) else None


def out_of_domain(score: float, policy: OODPolicy) -> bool:
    """True when ``score`` is above the policy's threshold (a NaN score, unavailable, is never out)."""
    return bool(policy.enabled and np.isfinite(score) and score > policy.threshold)


def skip_record(index: int, token: str, score: float, policy: OODPolicy, why: str = "") -> dict:
    """The ``frames_skipped`` entry of a dropped frame (``index``: its position in the drive; ``why``: words that
    replace the general reason, e.g. ``NetworkRunner.ood_cause``'s)."""
    return {"index": int(index), "token": token, "ood_score": float(score),
            "reason": f"out of domain: score {score:.2f} > {policy.threshold:g} "
                      f"({why or 'the input is unlike the frames the network was fitted on'}; frame dropped)"}


def decide(scores: list[float], policy: OODPolicy, note: str = "", unread: int = 0, frozen: int = 0,
           causes: Mapping[str, int] | None = None) -> dict:
    """The result's ``ood`` block: per-frame scores, counts, and ``inconclusive`` (reason, or ""). ``unread``:
    frames of the drive whose files did not read (no score): they count as not in domain, so a damaged copy of a
    root cannot earn more trust than the intact one by losing its doubtful frames (probe 15: 4 of 10 in domain on
    the intact root was inconclusive, the same 4 of 5 readable ones on a damaged copy was not); ``frozen``: frames
    whose camera image is an earlier frame's (``hybrid.drives.frozen_images``), counted alike; ``causes``: the
    out-of-domain frames counted by their camera image's cause (``learned.ood.CAUSES``' keys; ``NetworkRunner.
    ood_cause``), named in the words (a night drive was "inconclusive" without a word of its darkness)."""
    s = np.asarray(scores, np.float64)
    available = bool(policy.enabled and len(s) and np.all(np.isfinite(s)))
    block = {"available": available, "threshold": policy.threshold, "scores": [json_score(x) for x in s],
             "frames": int(len(s)), "in_domain": None, "inconclusive": "", "unread": int(unread),
             "frozen": int(frozen), "causes": {k: int(n) for k, n in (causes or {}).items() if n}}
    if not policy.enabled:
        block["note"] = "out-of-domain score disabled (--set ood.enabled=false)"
        return block
    if not available:
        block["note"] = note or "out-of-domain score unavailable for some frames"
        return block
    n_in = int(np.sum(s <= policy.threshold))
    block["in_domain"] = n_in
    total = len(s) + int(unread) + int(frozen)
    need = max(policy.min_in_domain_frames, int(np.ceil(policy.min_in_domain_fraction * total)))
    if n_in < need and total < policy.min_in_domain_frames and n_in == total:  # the drive, not the domain
        block["inconclusive"] = (
            f"the drive has {len(s)} frame{'s' if len(s) != 1 else ''} (all inside the network's training domain), "
            f"fewer than the {need} in-domain frames the out-of-domain test needs before it trusts the network's "
            "answer: calibrate on more frames (--max-frames, or a wider --split)")
    elif n_in < need:
        unread_words = (f"; {unread} of them did not read" if unread else "") + (
            f"; {frozen} of them repeat an earlier frame's camera image (a frozen camera)" if frozen else "")
        block["inconclusive"] = (
            f"only {n_in} of {total} frames are inside the network's training domain (out-of-domain score <= "
            f"{policy.threshold:g}; median score {np.median(s):.1f}{unread_words}), fewer than the {need} required: "
            f"the network's answer cannot be trusted on this input{cause_words(block['causes'], len(s) - n_in)}")
    return block


def cause_words(causes: Mapping[str, int], n_out: int) -> str:
    """"; of the N frames out of domain, K are dark (...)": the causes their camera images show, most frequent first
    (``learned.ood.CAUSES``); "" when none is seen."""
    from learned.ood import CAUSES

    named = [f"{n} {CAUSES[k]}" for k, n in sorted(causes.items(), key=lambda kv: -kv[1]) if n and k in CAUSES]
    return f"; of the {n_out} frames out of domain, {', '.join(named)}" if named and n_out else ""


def corrupt(sample: dict, kind: str, g: np.random.Generator, other: dict | None = None) -> dict:
    """A copy of a prepared sample (``NetworkRunner.sample``) with one corruption (``CORRUPTIONS``):
    ``noise-image``: the image replaced by uniform noise in [0, 1]; ``shuffled-radar``: the radar of
    ``other`` (another frame of the drive); ``blank-depth``: the depth map all zero (unknown)."""
    import torch

    s = dict(sample)
    if kind == "noise-image":
        s["image"] = torch.from_numpy(g.uniform(0, 1, tuple(sample["image"].shape)).astype(np.float32))
    elif kind == "shuffled-radar":
        if other is None:
            raise ValueError("shuffled-radar needs another frame's sample")
        s["radar"], s["radar_mask"] = other["radar"], other["radar_mask"]
    elif kind == "blank-depth":
        s["depth"] = torch.zeros_like(sample["depth"])
    else:
        raise ValueError(f"unknown corruption {kind!r}; valid: {CORRUPTIONS}")
    return s


def ood_passes(runner, indices: list[int], base: np.ndarray, start_range: str, seed: int, vehicle: str,
               corruption: str = "") -> list[dict]:
    """The network on each frame of ``indices`` from its own start drawn in ``start_range`` around
    ``base`` (truth or tables), optionally corrupted. Per frame: token, features (descriptor,
    signals), score (NaN without ``export.ood``), rotation / translation error of the final estimate
    against ``base`` (deg, cm) and its NEES with the checkpoint's ``cov_scale``."""
    from hybrid_calib.geometry import local
    from hybrid_calib.hybrid.network import mount_pass, on_mount
    from hybrid_calib.metrics import extrinsic_error, nees
    from hybrid_calib.perturbation import perturbed_start, vehicle_rng

    g = vehicle_rng(seed, vehicle, "ood")
    gc = vehicle_rng(seed, vehicle, "ood-corruption")
    recs = []
    for k, i in enumerate(indices):
        T0 = perturbed_start(base, g, start_range)
        if corruption:
            s = runner.sample(i)
            if s is None:
                continue
            other = None
            if corruption == "shuffled-radar":
                j = indices[(k + len(indices) // 2) % len(indices)]
                other = runner.sample(j)
                s = runner.sample(i)  # sample() keeps one frame
                if other is None or s is None:
                    continue
            N = runner.radar_motion(i)
            out = on_mount(runner.forward(corrupt(s, corruption, gc, other), T0 @ N), N)
        else:
            out = mount_pass(runner, i, T0)
        if out is None:
            continue
        e = local(base, out.T)
        err = extrinsic_error(out.T, base)
        recs.append({"index": int(i), "token": runner.token(i), "descriptor": out.ood_descriptor,
                     "signals": out.ood_signals, "score": runner.ood_score(out),
                     "rot_deg": float(err.geodesic_deg), "trans_cm": float(err.trans_norm_cm),
                     "nees": nees(e, runner.network_cov(out))})
    return recs
