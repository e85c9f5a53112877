"""Checkpoints: model weights (safetensors) + optimizer/scheduler state (``torch.save`` state dicts,
read back with ``weights_only=True``) + a JSON file with the epoch, the configs and the metrics.

Layout of one checkpoint with stem ``DIR/ckpt-0003``:
  ckpt-0003.safetensors  model ``state_dict`` (float32 tensors; the JSON config in its metadata too)
  ckpt-0003.optim.pt     ``{"optimizer": ..., "scheduler": ...}`` state dicts (training only)
  ckpt-0003.json         ``{"epoch", "model_config", "train_config", "metrics", "files"}``
Every file is written to a temp name and renamed; the JSON is written last, so a checkpoint exists
(``latest_checkpoint`` finds it) only once all its files are complete. ``files.weights_sha256`` is the
SHA-256 of the weights file: a JSON whose fitted models (``export``) belong to one network is not
loaded with another network's weights copied beside it (checked whenever the JSON holds it).

Reading is defensive: a missing, truncated or garbage JSON or ``.safetensors`` raises
``CheckpointError`` naming the file, and weights are only ever read from ``.safetensors`` (a JSON
whose ``files.weights`` names a pickle, e.g. ``.pt``/``.pth``/``.ckpt``, is rejected: unpickling can
run code). The optimizer state is read with ``torch.load(weights_only=True)``, which refuses
arbitrary objects.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

from hybrid_calib.atomic import atomic_path
from hybrid_calib.config import save_json_atomic
from hybrid_calib.errors import CheckpointError, HybridCalibError

_STEM = re.compile(r"^ckpt-(\d{4,})\.json$")
_PICKLE_SUFFIXES = (".pt", ".pth", ".ckpt", ".pkl", ".pickle", ".bin")


@dataclass
class Checkpoint:
    """What ``load_checkpoint`` returns. ``path`` is the JSON file."""

    path: Path
    epoch: int
    model_config: dict[str, Any]
    train_config: dict[str, Any] = field(default_factory=dict)
    metrics: dict[str, Any] = field(default_factory=dict)
    export: dict[str, Any] = field(default_factory=dict)  # ExportConfig overrides fitted on held-out data


def checkpoint_stem(directory: str | Path, epoch: int) -> Path:
    return Path(directory) / f"ckpt-{epoch:04d}"


def _umask_mode(path: Path) -> None:
    """Give ``path`` the permissions of a file created under the process's umask (safetensors writes its file 0600:
    the weights of a shared run folder were readable by their owner alone, the JSON beside them by everyone)."""
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(path, 0o666 & ~mask)


def save_checkpoint(stem: str | Path, model: torch.nn.Module, *, epoch: int, model_config: dict,
                    train_config: dict | None = None, metrics: dict | None = None,
                    optimizer: torch.optim.Optimizer | None = None, scheduler: Any = None,
                    data: dict | None = None) -> Path:
    """Write a checkpoint at ``stem`` (see module docstring); returns the JSON path. ``data``: what the training run
    read (``trained_data``), kept in the JSON so that it travels with a checkpoint copied out of its run folder."""
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    weights = stem.with_suffix(".safetensors")
    state = {k: v.detach().to("cpu").contiguous().clone() for k, v in model.state_dict().items()}
    with atomic_path(weights) as tmp:  # a failed write leaves no partial file behind
        # one metadata key: safetensors writes its metadata in hash-map order, so two keys made the same weights two
        # different files, half the time (probe 72: weights_sha256 of a same-seed retrain did not reproduce)
        save_file(state, str(tmp), metadata={"model_config": json.dumps(model_config, sort_keys=True)})
        _umask_mode(tmp)
    files = {"weights": weights.name, "weights_sha256": weights_sha256(weights)}
    if optimizer is not None:
        optim = stem.with_suffix(".optim.pt")
        # through an open file: given a path, torch.save names the zip's folder after it, the temporary name with
        # the writer's pid, so one state gave other bytes each run (probe 90)
        with atomic_path(optim) as tmp, open(tmp, "wb") as fh:
            torch.save({"optimizer": optimizer.state_dict(),
                        "scheduler": scheduler.state_dict() if scheduler is not None else None}, fh)
        files["optimizer"] = optim.name
    meta = {"epoch": int(epoch), "model_config": model_config, "train_config": train_config or {},
            "metrics": metrics or {}, "files": files, **({"data": data} if data is not None else {})}
    return save_json_atomic(stem.with_suffix(".json"), meta)


def latest_checkpoint(directory: str | Path) -> Path | None:
    """The JSON of the highest-epoch complete checkpoint in ``directory`` (None if there is none)."""
    directory = Path(directory)
    if not directory.is_dir():
        return None
    found = [(int(m.group(1)), p) for p in directory.iterdir() if (m := _STEM.match(p.name))]
    return max(found)[1] if found else None


def orphaned_weights(directory: str | Path, last: Path | None) -> list[Path]:
    """The ``ckpt-NNNN.safetensors`` in ``directory`` past ``last`` (the latest complete checkpoint's JSON, or None)
    without their JSON: a save cut short between its two files, or a JSON deleted; a resume trains them again."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    after = -1 if last is None else int(_STEM.match(last.name).group(1))
    found = [(int(m.group(1)), p) for p in directory.glob("ckpt-*.safetensors")
             if (m := _STEM.match(p.with_suffix(".json").name)) and int(m.group(1)) > after
             and not p.with_suffix(".json").is_file()]
    return [p for _, p in sorted(found)]


def _resolve(path: str | Path) -> Path:
    """A checkpoint given as its JSON, its .safetensors, its stem or a directory -> its JSON path."""
    path = Path(path)
    if path.is_dir():
        latest = latest_checkpoint(path)
        if latest is None:
            latest = latest_checkpoint(path / "checkpoints")
        if latest is None:
            named = sorted(p.name for p in path.glob("*.json") if p.with_suffix(".safetensors").is_file())[:4]
            raise HybridCalibError(f"no checkpoint (ckpt-NNNN.json) in {path}" + (
                f"; it holds named checkpoints ({', '.join(named)}): pass one of them, e.g. {path / named[0]}"
                if named else "; train one with `hybrid-calib train`"))
        return latest
    if path.suffix in _PICKLE_SUFFIXES:
        raise CheckpointError("this is a pickled checkpoint; hybrid-calib never loads pickles (they can run code "
                              "when loaded): pass a checkpoint JSON written by `hybrid-calib train`", path=str(path))
    given = path
    if path.suffix == ".safetensors":
        path = path.with_suffix(".json")
    elif path.suffix != ".json":
        path = path.with_name(path.name + ".json")
    if not path.is_file() and given.is_file() and given.suffix == ".safetensors":  # weights without their JSON
        raise CheckpointError(f"checkpoint incomplete: its JSON {path.name} (the model config and fitted models, "
                              "written by `hybrid-calib train` beside the weights) is missing; copy it beside "
                              f"{given.name}", path=str(given))
    if not path.is_file() and given.is_file():  # probe 37: "not found [file X.json]" for an existing file X
        raise CheckpointError(f"not a checkpoint: a checkpoint is a JSON (ckpt-NNNN.json or a named one) with its "
                              f".safetensors beside it, and {path.name} is not there; pass the checkpoint's JSON, or "
                              "its run folder", path=str(given))
    if not path.is_file() and path.exists():  # a FIFO, a device, a socket (probe 109: read "not found")
        from hybrid_calib.data.files import check_regular_file

        check_regular_file(path, "the checkpoint's JSON")
    if not path.is_file():
        raise CheckpointError("checkpoint not found (expected ckpt-NNNN.json with its .safetensors beside it, or "
                              "a run folder)", path=str(path))
    return path


def read_checkpoint_meta(path: str | Path) -> tuple[Path, dict[str, Any]]:
    """Resolve a checkpoint (``_resolve``) and read its JSON -> ``(json path, meta dict)``.

    ``CheckpointError`` naming the file when the JSON is unreadable, truncated, not an object, or
    lacks ``epoch`` / ``model_config`` / ``files.weights``."""
    path = _resolve(path)
    try:
        meta = json.loads(path.read_text(encoding="utf-8-sig"))  # a byte-order mark (a Windows editor) is no damage
    except json.JSONDecodeError as e:
        raise CheckpointError(f"checkpoint metadata is not valid JSON ({e.msg} at line {e.lineno} column "
                              f"{e.colno}); the file is truncated or corrupt: copy it again or pick another "
                              "checkpoint", path=str(path)) from None
    except (OSError, UnicodeDecodeError, RecursionError) as e:
        why = "it nests JSON too deeply: it is not a checkpoint" if isinstance(e, RecursionError) else e
        raise CheckpointError(f"cannot read checkpoint metadata: {why}", path=str(path)) from None
    files = meta.get("files") if isinstance(meta, dict) else None
    if not isinstance(meta, dict) or not isinstance(files, dict) or "weights" not in files \
            or not isinstance(meta.get("model_config"), dict) or not isinstance(meta.get("epoch"), int):
        raise CheckpointError("checkpoint metadata lacks epoch, model_config or files.weights; it is not a "
                              "hybrid-calib checkpoint (ckpt-NNNN.json written by `hybrid-calib train`)",
                              path=str(path))
    for key in ("train_config", "metrics", "export"):
        if not isinstance(meta.get(key, {}), dict):
            raise CheckpointError(f"checkpoint field {key!r} is a JSON {type(meta[key]).__name__}, not an object; the "
                                  "file is corrupt: fix it, copy it again or pick another checkpoint", path=str(path))
    if problem := _train_config_problem(meta):
        raise CheckpointError(f"checkpoint {problem}: the file is damaged; fix the field, copy it again or pick "
                              "another checkpoint", path=str(path))
    return path, meta


def _train_config_problem(meta: dict) -> str:
    """What is wrong with the ``train_config`` a checkpoint's use reads (its start range, its split, its depth's
    options), or "": a file without one read as trained on the simulator's true depth (probe 109: a simulated root's
    figures flattered, no word), "R9" read as a wrong --start and a bad split as a wrong --set."""
    from hybrid_calib.perturbation import RANGES

    if "train_config" not in meta:  # save_checkpoint always writes it ({} at least)
        return ("records no train_config (how its network was trained: start range, depth): a run would guess "
                "them")
    tc = meta["train_config"]
    if "perturbation" in tc and tc["perturbation"] not in RANGES:
        return f"train_config.perturbation is {tc['perturbation']!r}, not one of {sorted(RANGES)}"
    for key in ("split", "depth_options"):
        if key in tc and not isinstance(tc[key], dict):
            return f"train_config.{key} is {tc[key]!r}, not an object of options"
    return ""


def check_export(export: dict[str, Any], path: Path) -> None:
    """``CheckpointError`` naming the file when the ``export`` block cannot work: an unknown key (a typo
    is otherwise ignored), a ``cov_scale`` / ``sigma_scale`` outside ``ExportConfig``'s intervals (one or 6
    factors for ``cov_scale``), or a ``hybrid`` / ``ood`` block that is not an object (their fields are checked
    where they are used: ``hybrid_calib.hybrid.loop.measurement_config``, ``learned.ood``)."""
    import dataclasses

    from learned.export import ExportConfig, scale_problem

    keys = {f.name for f in dataclasses.fields(ExportConfig)}
    unknown = sorted(set(export) - keys)
    problem = (f"unknown key(s) {unknown} (valid: {sorted(keys)})" if unknown else
               scale_problem(export.get("cov_scale", 1.0), export.get("sigma_scale", 1.0)))
    if not problem:
        bad = [k for k in ("hybrid", "ood") if not isinstance(export.get(k, {}), dict)]
        problem = f"{bad[0]} is a JSON {type(export[bad[0]]).__name__}, not an object" if bad else ""
    if not problem and (where := _non_finite(export)):  # evaluate copied a NaN ood block into its records
        problem = f"{where} is not a finite number (NaN/inf)"
    if problem:
        raise CheckpointError(f"checkpoint export block: {problem}; fix it in the JSON, or remove the entry and "
                              "fit it again (cov_scale: hybrid-calib evaluate --split val --fit-uncertainty; "
                              "sigma_scale: benchmarks/correspondence_quality.py --fit-into; hybrid: "
                              "benchmarks/hybrid_fit.py --fit-into; ood: benchmarks/ood_fit.py)", path=str(path))


def _non_finite(value: Any, where: str = "") -> str:
    """Where in a JSON value (dotted keys, [i] indices) the first NaN/inf number sits, "" when none does."""
    import math

    if isinstance(value, float):
        return "" if math.isfinite(value) else where or "the value"
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for k, v in items:
        if found := _non_finite(v, f"{where}[{k}]" if isinstance(k, int) else f"{where}.{k}".lstrip(".")):
            return found
    return ""


def trained_data(checkpoint: str | Path) -> dict[str, Any]:
    """What the training run of ``checkpoint`` read ("data": roots, version, nsweeps and, since session 34, the roots'
    data stamps): the checkpoint JSON's own record, else its run folder's ``train_config.json``; {} when neither
    says (a shipped checkpoint records its data in words, in ``provenance``)."""
    try:
        path = _resolve(checkpoint)
        data = read_checkpoint_meta(path)[1].get("data")
        if not isinstance(data, dict):
            data = json.loads((path.resolve().parent.parent / "train_config.json").read_text()).get("data")
    except (OSError, ValueError, AttributeError, TypeError, RecursionError, CheckpointError):
        return {}
    return data if isinstance(data, dict) else {}


# what a checkpoint JSON records of how long its epoch took, not what the network computes: two same-seed trainings
# differ there only (probe 72: each retrain was "another network", its caches missed and compare refused its trials)
TIMING_METRICS = ("seconds",)


def checkpoint_digest(checkpoint: str | Path) -> str:
    """The identity of a checkpoint: SHA-1 of its JSON's content (keys sorted, without ``TIMING_METRICS``) and of its
    weights file's bytes: a retrained (to other weights) or edited checkpoint at the same path is another network; the
    same files under another path, or a same-seed retrain to the same weights, are the same one."""
    import hashlib

    path, meta = read_checkpoint_meta(checkpoint)
    metrics = meta.get("metrics")
    if isinstance(metrics, dict):
        meta = {**meta, "metrics": {k: v for k, v in metrics.items() if k not in TIMING_METRICS}}
    h = hashlib.sha1(json.dumps(meta, sort_keys=True, allow_nan=True).encode())
    h.update(b"/")
    _hash_file(h, _weights_path(path, meta))
    h.update(b"/")
    return h.hexdigest()


def _hash_file(h, path: str | Path):
    """``h`` (a ``hashlib`` object) updated with the bytes of ``path``, read in 1 MiB chunks; returns ``h``."""
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h


def weights_sha256(weights: str | Path) -> str:
    """SHA-256 (hex) of a weights file's bytes: ``files.weights_sha256`` of a checkpoint JSON."""
    import hashlib

    return _hash_file(hashlib.sha256(), weights).hexdigest()


def check_weights_file(path: Path, meta: dict[str, Any], weights: Path) -> None:
    """``CheckpointError`` when the JSON records the SHA-256 of its weights and the file beside it is another
    (a network copied over it: the JSON's fitted models would be applied to weights they were not fitted on)."""
    want = meta["files"].get("weights_sha256")
    if want is None:
        fitted = sorted(k for k in ("cov_scale", "hybrid", "ood") if k in (meta.get("export") or {}))
        if fitted:  # said (probe 109: another network's weights under its name showed only as "out of domain")
            import warnings

            warnings.warn(f"checkpoint {path} records no files.weights_sha256, so its weights {weights.name} are not "
                          f"checked to be those its fitted export.{' / export.'.join(fitted)} were fitted on",
                          stacklevel=2)
        return
    if not isinstance(want, str) or (got := weights_sha256(weights)) != want.lower():
        raise CheckpointError(f"the weights file {weights.name} is not the one this checkpoint was saved with (its "
                              f"SHA-256 {got[:12] if isinstance(want, str) else '?'}... against files.weights_sha256 "
                              f"{str(want)[:12]}...): it was replaced or edited, and the fitted models in this JSON "
                              "belong to the original; copy the matching .safetensors beside it (or, for weights you "
                              "converted on purpose, remove files.weights_sha256 and refit the models)",
                              path=str(path))


def check_config_of_weights(path: Path, meta: dict[str, Any], weights: Path) -> None:
    """``CheckpointError`` when the JSON's ``model_config`` differs from the one saved in its weights' metadata
    (``save_checkpoint`` writes both): ``input_hw``, ``iterations`` or ``variant`` change no tensor shape, so a JSON
    edited there loaded silently, its fitted models applied to another network (probe 33: an edited input size read
    NEES 33 with coverage 12 %, exit 0). Weights without that metadata (converted elsewhere) are not checked."""
    from safetensors import safe_open

    try:
        with safe_open(str(weights), "pt") as f:
            saved = json.loads((f.metadata() or {}).get("model_config", "null"))
    except Exception:  # noqa: BLE001 (an unreadable file or metadata is _load_weights' to name; nothing to compare)
        return
    if not isinstance(saved, dict):
        return
    own = json.loads(json.dumps(meta["model_config"]))
    diff = sorted(k for k in set(saved) | set(own) if saved.get(k, "(absent)") != own.get(k, "(absent)"))
    if diff:
        k = diff[0]
        json_v, weights_v = json.dumps(own.get(k, "(absent)")), json.dumps(saved.get(k, "(absent)"))
        raise CheckpointError(f"its model_config differs from the one its weights {weights.name} were saved with, in "
                              f"{len(diff)} key(s): {', '.join(diff[:6])}{', ...' if len(diff) > 6 else ''} (e.g. "
                              f"{k}: {json_v} in the JSON, {weights_v} in the weights): the JSON was edited, and its "
                              "fitted models belong to the saved network; restore the JSON's model_config (or copy "
                              "the checkpoint again)", path=str(path))


def _beside(path: Path, name: str, field: str) -> Path:
    """The file ``name`` of ``files.<field>`` next to the checkpoint JSON ``path``. A name with folders is refused:
    a checkpoint's files sit beside its JSON, and ``../x`` or an absolute path had read the same-named file beside
    it while the JSON named another (probe 109, LOW)."""
    if not name or Path(name).name != name or "\\" in name:
        raise CheckpointError(f"checkpoint's files.{field} {name!r} is not a plain file name: a checkpoint's files sit "
                              f"next to its JSON and files.{field} names one of them (e.g. "
                              f"{Path(name.replace(chr(92), '/')).name or 'ckpt-0001.safetensors'!r}); copy the file "
                              "there and write its name alone", path=str(path))
    return path.parent / name


def _weights_path(path: Path, meta: dict[str, Any]) -> Path:
    """The ``.safetensors`` file a checkpoint JSON names, checked to be one (never a pickle) and present."""
    name = str(meta["files"]["weights"])
    weights = _beside(path, name, "weights")
    if weights.suffix != ".safetensors":
        raise CheckpointError(f"checkpoint names weights {name!r}, which is not a .safetensors file; hybrid-calib "
                              "never loads pickled weights (.pt/.pth/.ckpt can run code when loaded): convert "
                              "them to safetensors", path=str(path))
    if weights.is_dir():  # probe 87: read "missing"
        raise CheckpointError(f"the weights file {weights.name} of this checkpoint is a folder, not the weights "
                              "file (which must sit next to the JSON); put the file there", path=str(path))
    if not weights.is_file():
        raise CheckpointError(f"the weights file {weights.name} of this checkpoint is missing (it must sit next "
                              "to the JSON); copy it along", path=str(path))
    if not os.access(weights, os.R_OK):  # safetensors says "No such file or directory" (probe 111)
        raise CheckpointError("the weights file cannot be read (permission denied): give this user read access to "
                              "it (chmod +r)", path=str(weights))
    return weights


def _load_weights(weights: Path, device: str) -> dict[str, torch.Tensor]:
    from safetensors import SafetensorError

    try:
        return load_file(str(weights), device=device)
    except OSError as e:  # safetensors' own words for any file it cannot open ("No such file or directory" for a
        # file without read permission: probe 111's internal error)
        raise CheckpointError(f"the weights file cannot be read ({e.strerror or e}): check that it is there and this "
                              "user may read it", path=str(weights)) from None
    except SafetensorError as e:  # a bad header or body; also safetensors' word for a device name it does not know
        if str(e).startswith(f"device {device} "):
            raise CheckpointError(f"device {device!r} is not a torch device ({e}); use cpu, cuda or cuda:N",
                                  path=str(weights)) from None
        raise CheckpointError(f"weights file is not a valid safetensors file ({e}); it is truncated or corrupt: "
                              "copy it again or pick another checkpoint", path=str(weights)) from None
    except RuntimeError as e:  # the file is fine: the device is not on this machine (no CUDA here)
        raise CheckpointError(f"the weights cannot be placed on device {device!r} ({str(e).splitlines()[0][:160]}); "
                              "use a device this machine has (cpu)", path=str(weights)) from None


def state_mismatch(expected: dict, got: dict, show: int = 2) -> str:
    """One line on how the state dict ``got`` differs from ``expected`` (name -> tensor): the tensors of
    the wrong shape, missing and unexpected, with counts and the first ``show`` of each."""
    def first(names: list[str], fmt=str) -> str:
        return ", ".join(fmt(n) for n in names[:show]) + (", ..." if len(names) > show else "")

    shape = [k for k in expected if k in got and tuple(got[k].shape) != tuple(expected[k].shape)]
    missing = [k for k in expected if k not in got]
    unexpected = [k for k in got if k not in expected]
    parts = []
    if shape:
        parts.append(f"{len(shape)} of the wrong shape: " + first(
            shape, lambda k: f"{k} {list(got[k].shape)} instead of {list(expected[k].shape)}"))
    if missing:
        parts.append(f"{len(missing)} missing: {first(missing)}")
    if unexpected:
        parts.append(f"{len(unexpected)} unexpected: {first(unexpected)}")
    return "; ".join(parts) or "the tensors differ in dtype"


def check_weight_values(state: dict, expected: dict, weights: Path) -> None:
    """``CheckpointError`` naming ``weights`` when a tensor holds NaN/inf (a diverged training run; every
    estimate would be NaN) or is an integer tensor where the model has a floating one (its values would be
    rounded silently by ``load_state_dict``). Float16/32/64 all load, and so does a float counter
    (``num_batches_tracked``)."""
    kind = [k for k, v in state.items() if k in expected and expected[k].is_floating_point()
            and not v.is_floating_point()]
    if kind:
        raise CheckpointError(f"weights hold {len(kind)} tensor(s) of the wrong kind of dtype (first: {kind[0]} is "
                              f"{state[kind[0]].dtype}, the model's is {expected[kind[0]].dtype}); the weights file "
                              "was converted wrongly: copy the original or pick another checkpoint", path=str(weights))
    bad = [k for k, v in state.items() if v.is_floating_point() and not bool(torch.isfinite(v).all())]
    if bad:
        raise CheckpointError(f"weights hold NaN/inf values in {len(bad)} tensor(s) (first: {bad[0]}); the training "
                              "run diverged or the file is corrupt: pick an earlier checkpoint of the run",
                              path=str(weights))


def load_checkpoint(path: str | Path, model: torch.nn.Module | None = None,
                    optimizer: torch.optim.Optimizer | None = None, scheduler: Any = None,
                    map_location: str | torch.device = "cpu") -> Checkpoint:
    """Read a checkpoint; load its weights into ``model`` (strict) and its state into ``optimizer``
    / ``scheduler`` when given. Raises ``CheckpointError`` / ``HybridCalibError`` naming the file on
    any problem (missing, truncated, garbage, a pickle, a mismatch)."""
    path, meta = read_checkpoint_meta(path)
    check_export(meta.get("export", {}), path)
    ckpt = Checkpoint(path, int(meta["epoch"]), meta["model_config"], meta.get("train_config", {}),
                      meta.get("metrics", {}), meta.get("export", {}))
    if model is not None:
        weights = _weights_path(path, meta)
        state = _load_weights(weights, str(map_location))
        check_weight_values(state, model.state_dict(), weights)
        try:
            model.load_state_dict(state, strict=True)
        except RuntimeError:
            # the JSON's model_config edited (a deleted feat_dim built a model of the default width) is what is
            # wrong when the weights carry the config they were saved with: said so, not blamed on the weights
            check_config_of_weights(path, meta, weights)
            raise CheckpointError(f"weights do not fit this model ({state_mismatch(model.state_dict(), state)}); "
                                  "the weights file does not belong to this checkpoint's model_config: copy the "
                                  "matching .safetensors or pick another checkpoint", path=str(weights)) from None
        check_weights_file(path, meta, weights)
        check_config_of_weights(path, meta, weights)
    if optimizer is not None or scheduler is not None:
        name = meta["files"].get("optimizer")
        if name is None:
            raise HybridCalibError(f"checkpoint {path} has no optimizer state; cannot resume training from it")
        optim = _beside(path, str(name), "optimizer")
        try:
            state = torch.load(optim, map_location=map_location, weights_only=True)
            if not isinstance(state, dict) or not isinstance(state.get("optimizer"), dict):
                raise TypeError("no 'optimizer' state dict in it")
        except Exception as e:  # torch.load raises RuntimeError / UnpicklingError / EOFError / OSError
            why = f"{type(e).__name__}: {str(e).strip().splitlines()[0][:160] if str(e).strip() else '-'}"  # not
            # PyTorch's whole weights_only paragraph
            raise CheckpointError(f"optimizer state is missing, corrupt or not a plain state dict ({why}); start a "
                                  "new run with --init on this checkpoint instead of resuming",
                                  path=str(optim)) from None
        try:
            if optimizer is not None:
                optimizer.load_state_dict(state["optimizer"])
            if scheduler is not None and state.get("scheduler") is not None:
                scheduler.load_state_dict(state["scheduler"])
        except (ValueError, KeyError, TypeError) as e:  # a state of another model or optimizer configuration
            why = f"{type(e).__name__}: {str(e).strip().splitlines()[0][:160] if str(e).strip() else '-'}"
            raise CheckpointError(f"the optimizer state does not fit this run's model and optimizer ({why}): the run's "
                                  "--set model.* or training options differ from the checkpoint's; start a new run "
                                  "with --init on this checkpoint instead of resuming", path=str(optim)) from None
    return ckpt


def set_export_overrides(path: str | Path, overrides: dict[str, Any], note: str = "") -> Path:
    """Store ``learned.export.ExportConfig`` overrides (e.g. a fitted ``cov_scale``) in a checkpoint's
    JSON (``"export"``, merged into what is there; ``note`` says how they were fitted). A value it replaces is
    kept, with its note and the time, in ``"export_history"`` (a refit on four frames silently replaced one
    fitted on 240). Atomic."""
    import datetime

    path, meta = read_checkpoint_meta(path)
    old = meta.get("export") or {}
    when = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    meta.setdefault("export_history", []).extend(
        {"key": k, "value": old[k], "note": (meta.get("export_notes") or {}).get(k, ""), "replaced_at": when}
        for k in overrides if k in old and old[k] != overrides[k])
    meta["export"] = {**old, **overrides}
    if note:
        meta.setdefault("export_notes", {}).update({k: note for k in overrides})
    return save_json_atomic(path, meta)


def load_model(path: str | Path, device: str | torch.device = "cpu", model_factory=None):
    """Build the network (``model_factory``, default ``learned.model.RCAutoCalib``) from a
    checkpoint's own model config and load its weights. Returns ``(model in eval mode, Checkpoint)``."""
    from learned.config import model_config

    if model_factory is None:
        from learned.model import RCAutoCalib as model_factory
    path, meta = read_checkpoint_meta(path)
    try:
        cfg = model_config(meta["model_config"])
    except HybridCalibError as e:  # ConfigError: its "--set model.KEY" hint names the field
        raise CheckpointError(f"checkpoint model_config is invalid: {e}; the JSON was edited or is corrupt: fix "
                              "that field, copy the file again or pick another checkpoint", path=str(path)) from None
    model = model_factory(cfg)
    ckpt = load_checkpoint(path, model, map_location="cpu")
    try:
        return model.to(device).eval(), ckpt
    except (RuntimeError, AssertionError) as e:  # an unknown device name; CUDA on a CPU build of torch
        raise CheckpointError(f"the network cannot be placed on device {str(device)!r} "
                              f"({str(e).splitlines()[0][:160] if str(e) else type(e).__name__}); use a device this "
                              "machine has (cpu)", path=str(path)) from None
