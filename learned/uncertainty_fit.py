"""Fitting the exported covariance's per-axis scale on held-out frames (``hybrid-calib evaluate --fit-uncertainty``).

The refusals come first (``check_fit``): a fit on the test split, on a real root (its tables are no truth), on the
training frames, or into a checkpoint shipped with the package would store a scale that looks honest where it was
fitted. ``fit_uncertainty`` then reads an evaluate run's exported errors and covariances, fits ``cov_scale`` per axis
(``learned.export.calibrate_cov_scale``) and writes it into the checkpoint's export block with a note.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from hybrid_calib.errors import HybridCalibError


def refuse_shipped(path: str | Path) -> None:
    """``HybridCalibError`` when ``path`` is one of the checkpoints shipped inside the installed package: a fit
    written there would change every later run of every user of this installation."""
    import learned

    shipped = (Path(learned.__file__).parent / "checkpoints").resolve()
    if Path(path).resolve().is_relative_to(shipped):
        raise HybridCalibError(f"--fit-uncertainty would rewrite {path}, a checkpoint shipped with the package; copy "
                               "its .json and .safetensors into a folder of yours and pass the copy as --checkpoint")


def trained_on(checkpoint: str | Path, roots, version: str | None = None, stamps: list[str] | None = None
               ) -> list[str]:
    """The ``roots`` the training run of ``checkpoint`` read (``learned.checkpoint.trained_data``): at the same path,
    or (with ``version``) holding the same data at another (its data stamp: a ``cp -r`` of the training root, probe
    55); [] when the run does not say (a shipped checkpoint records its data in words, in ``provenance``).
    ``stamps``: the roots' ``data_stamp`` digests when the caller has them (each hashes the root's tables)."""
    from hybrid_calib.data.files import data_stamp
    from learned.checkpoint import trained_data

    data = trained_data(checkpoint)
    try:
        seen = {str(Path(r).resolve()) for r in data.get("roots", [])}
        trained = set(data.get("stamps") or []) if version is not None else set()
    except (TypeError, ValueError):
        return []
    digests = list(stamps) if stamps is not None else [None] * len(roots)
    return [str(r) for r, digest in zip(roots, digests) if str(Path(r).resolve()) in seen
            or (trained and (digest if digest is not None else data_stamp(r, version)["digest"]) in trained)]


def training_overlap(checkpoint: str | Path, frames, roots, version: str, split: str,
                     split_options: dict | None, stamps: list[str] | None = None) -> int | None:
    """How many of the frames of ``split`` ("test" / "val", under ``split_options``) the training run of
    ``checkpoint`` trained on (its recorded ``train_config.split`` over the same frames): 0 when none (a root it
    never read, or the checkpoint's own split), None when it cannot be told (the run read these roots among
    others: its split was over another list of frames). Probe 55: ``--split-by`` / fraction flags other than the
    checkpoint's put 8 of its 16 training frames in a "held-out" val split, and a fit went into the checkpoint."""
    from learned.checkpoint import read_checkpoint_meta, trained_data
    from learned.dataset import split_indices

    if split not in ("test", "val") or not (seen := trained_on(checkpoint, roots, version, stamps)):
        return 0
    trained = (read_checkpoint_meta(checkpoint)[1].get("train_config") or {}).get("split")
    if not isinstance(trained, dict) or trained == (split_options or {}):
        return 0
    data = trained_data(checkpoint)
    if len(seen) != len(roots) or len(data.get("roots") or []) != len(roots) or data.get("version") != version:
        return None
    held = set(split_indices(frames, split, split_options or {}))
    return len(held & set(split_indices(frames, "train", trained)))


def overlap_words(n: int | None, split: str) -> str:
    """The words for ``training_overlap`` (``n`` > 0 or None)."""
    return (f"{n} of the --split {split} frames" if n is not None else f"--split {split} may hold frames that") + \
        (" the checkpoint was trained on (the split flags differ from its recorded split, train_config.split)")


def check_fit(checkpoint: str | Path, roots, split: str, version: str, refine: bool,
              perturbation: str | None = None) -> None:
    """``HybridCalibError`` for a fit that would not be held out: with ``--refine`` (several checkpoints), on the test
    split, on a real root (``data.nuscenes.simulated_root``: whatever the folder's name), on the frames ``checkpoint``
    was trained on, or into a shipped checkpoint."""
    from hybrid_calib.data.nuscenes import simulated_root

    if refine:
        raise HybridCalibError("--fit-uncertainty fits one checkpoint's covariance; run it on each checkpoint "
                               "alone, without --refine")
    if split == "test":
        raise HybridCalibError("--fit-uncertainty on the test split would leave nothing held out to check it; "
                               "fit with --split val (or --split all on a separate root)")
    # errors against the tables, out-of-domain frames among them (probe 141: the folder's name was the test, and a
    # real root in a folder named v1.0-sim had its tables fitted as the truth)
    if real := [str(r) for r in roots if not simulated_root(r, version)]:
        raise HybridCalibError(f"--fit-uncertainty on {', '.join(real)}, a real root (no simulator truth: "
                               f"sim_vehicle.json with vehicle records): it has no ground truth, only its "
                               "tables (themselves a few tenths of a degree off) and frames outside the network's "
                               "domain, so the fitted scale would be the tables' and the domain gap's; fit on "
                               "simulated validation drives (v1.0-sim), or, for a network fine-tuned on real "
                               "frames, with benchmarks/real_finetune.py (its scale floored at 1)")
    if split in ("all", "train") and (seen := trained_on(checkpoint, roots, version)):
        raise HybridCalibError(f"--fit-uncertainty with --split {split} on {', '.join(seen)}, a root the "
                               f"checkpoint was trained on ({checkpoint}): its frames would make the covariance "
                               "look honest where it was fitted; use --split val, or a root it never saw")
    from learned.checkpoint import read_checkpoint_meta

    trained = (read_checkpoint_meta(checkpoint)[1].get("train_config") or {}).get("perturbation")
    if perturbation is not None and isinstance(trained, str) and trained != perturbation:
        # probe 55: R0 starts on an R1 network stored a scale 5-80x too small for the R1 starts it is used on
        raise HybridCalibError(f"--fit-uncertainty with --range {perturbation} on a checkpoint trained on {trained} "
                               f"starts ({checkpoint}): the scale would be fitted to errors of starts it is not used "
                               f"on; fit with --range {trained}")
    refuse_shipped(checkpoint)


@dataclass(frozen=True)
class FitResult:
    """What ``fit_uncertainty`` wrote: the per-axis ``cov_scale`` (6,) [radar tangent: rotation x3, translation x3],
    the frames it rests on, the scale it replaced (with its note) and the export keys fitted under the old scale."""

    checkpoint: Path
    cov_scale: list[float]
    n_frames: int
    replaced: tuple | None = None  # (old cov_scale, its note) or None
    stale: list[str] = field(default_factory=list)  # export.hybrid / sigma_scale: fitted with the earlier scale


def fit_uncertainty(out: str | Path, checkpoint: str | Path, roots, split: str, perturbation: str,
                    min_frames: int) -> FitResult:
    """Fit the exported covariance's per-axis scale on the frames an evaluate run wrote into ``out`` and store it in
    ``checkpoint``'s export block (``HybridCalibError`` with fewer than ``min_frames`` frames: nothing written)."""
    from learned.checkpoint import read_checkpoint_meta, set_export_overrides
    from learned.evaluate import tangent_errors
    from learned.export import calibrate_cov_scale

    errors, covs = tangent_errors(out)
    if not len(errors):
        raise HybridCalibError(f"no exported covariances in {out}; nothing to fit")
    if len(errors) < min_frames:  # six variances from a handful of frames would be stored as the network's truth
        raise HybridCalibError(f"--fit-uncertainty: {len(errors)} frames with an exported covariance, fewer than "
                               f"{min_frames} (a variance from n frames is good to sqrt(2/n)); nothing was written to "
                               f"{checkpoint}: fit on more validation frames (drop --max-frames, add roots), or "
                               "pass --set fit_min_frames=N to accept fewer")
    scale = calibrate_cov_scale(errors, covs, per_axis=True)
    note = (f"per-axis fit on {len(errors)} frames of {' '.join(str(d) for d in roots)} (split {split}, range "
            f"{perturbation}) by hybrid-calib evaluate --fit-uncertainty")
    _, meta = read_checkpoint_meta(checkpoint)
    before, notes = meta.get("export") or {}, meta.get("export_notes") or {}
    set_export_overrides(checkpoint, {"cov_scale": scale}, note)
    replaced = (before["cov_scale"], notes.get("cov_scale") or "no note") if "cov_scale" in before else None
    return FitResult(Path(checkpoint), [float(v) for v in scale], len(errors), replaced,
                     [k for k in ("hybrid", "sigma_scale") if k in before])
