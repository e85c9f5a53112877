"""The command line's error boundary: bad input, tried as a new user would, ends in one clear message
on stderr that names the file / option and what to do, a non-zero exit, and no traceback
(``hybrid_calib.cli.main``). Commands run in-process on tiny data, so the whole file takes seconds."""

from __future__ import annotations

import json
import shutil
import warnings

import numpy as np
import pytest
import torch

from hybrid_calib.cli import EXIT_BUG, EXIT_ERROR, main
from hybrid_calib.config import ConfigError, check_type, merge
from hybrid_calib.errors import CheckpointError, HybridCalibError, OptionError, check_out_dir
from learned.checkpoint import load_checkpoint, save_checkpoint
from tests.helpers import expect_cli_error
from tests.tiny_nuscenes import VERSION, corrupt_jpeg_scan, make_tiny_root


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A clean tiny root shared by the cases that do not change it."""
    return make_tiny_root(tmp_path_factory.mktemp("tiny") / "root", n_samples=3)


@pytest.fixture
def tiny_copy(tiny, tmp_path):
    """A private copy of the tiny root, for cases that corrupt it."""
    root = tmp_path / "copy"
    shutil.copytree(tiny.root, root)
    return root


def _expect_error(argv, capsys, *needles, rc=EXIT_ERROR) -> str:
    return expect_cli_error(argv, capsys, *needles, rc=rc)


def _data_args(command: str, root, out) -> list:
    return {
        "inspect": ["inspect", "--data", root, "--version", VERSION, "--no-progress"],
        "calibrate": ["calibrate", "--data", root, "--version", VERSION, "--out", out, "--no-plots"],
        "fleet": ["fleet", "--data", root, "--version", VERSION, "--out", out, "--no-plots"],
        "train": ["train", "--data", root, "--version", VERSION, "--out", out, "--no-progress"],
        "evaluate": ["evaluate", "--data", root, "--version", VERSION, "--out", out, "--no-progress",
                     "--checkpoint", out / "none.json"],
    }[command]


DATA_COMMANDS = ("inspect", "calibrate", "train", "evaluate")


# ---------------------------------------------------------------- roots, versions, tables
@pytest.mark.parametrize("command", ("inspect", "calibrate", "train", "fleet"))  # evaluate reads its checkpoint first
def test_missing_root(command, tmp_path, capsys):
    _expect_error(_data_args(command, tmp_path / "nowhere", tmp_path / "out"), capsys,
                  "does not exist", tmp_path / "nowhere")


@pytest.mark.parametrize("command", ("inspect", "calibrate", "train", "fleet"))
def test_wrong_version_lists_the_versions(command, tiny, tmp_path, capsys):
    argv = [a if a != VERSION else "v1.0-trainval" for a in _data_args(command, tiny.root, tmp_path / "out")]
    _expect_error(argv, capsys, "'v1.0-trainval' does not exist", VERSION, "--version")


@pytest.mark.parametrize("command", ("inspect", "calibrate", "train", "fleet"))
@pytest.mark.parametrize("case", ["missing-table", "corrupt-table", "duplicate-token", "no-samples"])
def test_bad_tables(command, case, tiny_copy, tmp_path, capsys):
    vdir = tiny_copy / VERSION
    if case == "missing-table":
        (vdir / "log.json").unlink()
        needles = ("table 'log' is missing", vdir / "log.json")
    elif case == "corrupt-table":
        (vdir / "sample_data.json").write_text((vdir / "sample_data.json").read_text()[:500])
        needles = ("not valid JSON", vdir / "sample_data.json")
    elif case == "duplicate-token":
        recs = json.loads((vdir / "ego_pose.json").read_text())
        (vdir / "ego_pose.json").write_text(json.dumps(recs + [dict(recs[2])]))
        needles = ("token appears twice", recs[2]["token"], vdir / "ego_pose.json")
    else:
        (vdir / "sample.json").write_text("[]")
        needles = ("holds no samples", vdir / "sample.json")
    _expect_error(_data_args(command, tiny_copy, tmp_path / "out"), capsys, *needles)


# ---------------------------------------------------------------- --set
SET_CASES = [
    # (command, override, words the message must hold)
    ("inspect", "nosuchkey=1", ["nosuchkey", "valid options"]),
    ("inspect", "nsweeps=abc", ["nsweeps='abc'", "integer"]),
    ("inspect", "load_lidar=off", ["load_lidar='off'", "bool"]),
    ("inspect", "on_error=ignore", ["on_error", "'skip' or 'raise'"]),
    ("inspect", "nsweeps", ["--set 'nsweeps'", "KEY=VALUE"]),
    ("inspect", "radar_filter=5", ["radar_filter=5", "--set radar_filter.KEY=VALUE"]),
    ("calibrate", "nosuchkey=1", ["nosuchkey", "CalibrateConfig"]),
    ("calibrate", "oracle.outlier_frac=abc", ["oracle.outlier_frac='abc'", "number"]),
    ("calibrate", "window.factor.kernel=nosuch", ["kernel='nosuch'", "tukey"]),
    ("calibrate", "window.window=0", ["window", "must be >= 1, got 0"]),
    ("train", "nosuchkey=1", ["nosuchkey", "TrainConfig"]),
    ("train", "lr=abc", ["lr='abc'", "number"]),
    ("train", "model.use_mca=off", ["model.use_mca='off'", "bool", "--set model.use_mca=true"]),
    ("evaluate", "nosuchkey=1", ["nosuchkey", "EvalConfig"]),
    ("evaluate", "batch_size=abc", ["batch_size='abc'", "integer"]),
]


@pytest.mark.parametrize("command,override,needles", SET_CASES, ids=[f"{c}-{o}" for c, o, _ in SET_CASES])
def test_bad_set_is_a_clear_error(command, override, needles, tiny, tmp_path, capsys):
    _expect_error(_data_args(command, tiny.root, tmp_path / "out") + ["--set", override], capsys, *needles)


@pytest.mark.parametrize("argv,needles", [
    (["simulate", "--set", "image_scale=abc"], ["image_scale='abc'", "number"]),
    (["simulate", "--set", "radar.nosuch=1"], ["nosuch", "RadarConfig at radar;"]),
    (["demo", "--set", "frames=abc"], ["frames='abc'", "integer"]),
    (["demo", "--set", "start=R9"], ["'R9'", "R1"]),
    (["demo", "--set", "frames=0"], ["frames=0"]),
], ids=["sim-type", "sim-nested-unknown", "demo-type", "demo-enum", "demo-zero"])
def test_bad_set_simulate_and_demo(argv, needles, tmp_path, capsys):
    _expect_error(argv + ["--out", tmp_path / "out"], capsys, *needles)
    assert not (tmp_path / "out").exists()  # checked before anything is written


# ---------------------------------------------------------------- --out and counts
@pytest.mark.parametrize("command", ["simulate", "demo", *DATA_COMMANDS])
def test_out_that_is_a_file(command, tiny, tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("x")
    argv = _data_args(command, tiny.root, afile) if command in DATA_COMMANDS else [command, "--out", afile]
    if command == "inspect":
        argv += ["--out", afile]
    _expect_error(argv, capsys, "--out", afile, "existing file")
    assert afile.read_text() == "x"


def test_out_below_a_file(tmp_path):
    (tmp_path / "afile").write_text("x")
    with pytest.raises(OptionError, match="is a file"):
        check_out_dir(tmp_path / "afile" / "run")
    check_out_dir(tmp_path / "new" / "run")  # a directory to create is fine


@pytest.mark.parametrize("argv,option", [
    (["simulate", "--frames", "0"], "--frames"),
    (["simulate", "--vehicles", "-1"], "--vehicles"),
    (["simulate", "--workers", "0"], "--workers"),
    (["simulate", "--frames", "x"], "--frames"),
    (["calibrate", "--data", "d", "--window", "0"], "--window"),
    (["calibrate", "--data", "d", "--max-frames", "-1"], "--max-frames"),
    (["train", "--data", "d", "--epochs", "0"], "--epochs"),
    (["evaluate", "--data", "d", "--checkpoint", "c", "--max-frames", "-2"], "--max-frames"),
    (["inspect", "--data", "d", "--version", "v", "--nsweeps", "0"], "--nsweeps"),
], ids=lambda v: " ".join(v) if isinstance(v, list) else v)
def test_bad_counts_are_usage_errors(argv, option, tmp_path, capsys):
    _expect_error(argv + ["--out", tmp_path / "out"], capsys, f"argument {option}:")


def test_change_frame_outside_the_drive(tmp_path, capsys):
    _expect_error(["simulate", "--out", tmp_path / "s", "--frames", "4", "--extrinsic-change", "step",
                   "--change-frame", "9"], capsys, "--change-frame", "0..3")


def test_inspect_frame_out_of_range(tiny, tmp_path, capsys):
    _expect_error(_data_args("inspect", tiny.root, tmp_path) + ["--out", tmp_path / "o", "--frame", "7"], capsys,
                  "--frame", "3 frames")


# ---------------------------------------------------------------- checkpoints
@pytest.fixture
def small_ckpt(tmp_path):
    model = torch.nn.Linear(3, 2)
    path = save_checkpoint(tmp_path / "ck" / "ckpt-0001", model, epoch=1, model_config={"k": 1},
                           optimizer=torch.optim.SGD(model.parameters(), lr=0.1))
    return path, model


@pytest.mark.parametrize("case", ["missing-json", "truncated-json", "not-a-checkpoint", "missing-weights",
                                  "weights-a-folder", "truncated-weights", "garbage-weights", "json-names-a-pickle",
                                  "pickle-path", "corrupt-optimizer"])
def test_bad_checkpoint_names_the_file(case, small_ckpt, tmp_path):
    path, model = small_ckpt
    weights = path.with_suffix(".safetensors")
    kwargs = {"model": torch.nn.Linear(3, 2)}
    named = path
    if case == "missing-json":
        path.unlink()
    elif case == "truncated-json":
        path.write_text(path.read_text()[:40])
    elif case == "not-a-checkpoint":
        path.write_text(json.dumps({"epoch": 1}))
    elif case == "missing-weights":
        weights.unlink()
    elif case == "weights-a-folder":  # probe 87: read "missing"
        weights.unlink()
        weights.mkdir()
    elif case in ("truncated-weights", "garbage-weights"):
        weights.write_bytes(weights.read_bytes()[:30] if case == "truncated-weights" else bytes(range(256)) * 4)
        named = weights
    elif case == "json-names-a-pickle":
        meta = json.loads(path.read_text())
        meta["files"]["weights"] = "ckpt-0001.pt"
        path.write_text(json.dumps(meta))
        torch.save(model.state_dict(), path.with_suffix(".pt"))
    elif case == "pickle-path":
        torch.save(model.state_dict(), tmp_path / "model.pt")
        path = named = tmp_path / "model.pt"
    else:
        path.with_suffix(".optim.pt").write_bytes(b"garbage")
        kwargs["optimizer"] = torch.optim.SGD(kwargs["model"].parameters(), lr=0.1)
        named = path.with_suffix(".optim.pt")
    with pytest.raises(CheckpointError) as e:
        load_checkpoint(path, **kwargs)
    assert str(named) in str(e.value)
    if "pickle" in case:
        assert "never loads pickle" in str(e.value)
    if case == "weights-a-folder":
        assert "is a folder, not the weights file" in str(e.value)


@pytest.mark.parametrize("way", ["no-read-permission", "safetensors-cannot-open"])
def test_unreadable_weights_are_said_as_such(way, small_ckpt, monkeypatch):
    """Probe 111: weights without read permission were "internal error: FileNotFoundError: No such file or
    directory" (safetensors' words for any file it cannot open) in evaluate, train --init and fleet."""
    import os

    import learned.checkpoint as checkpoint

    path, _ = small_ckpt
    weights = path.with_suffix(".safetensors")
    if way == "no-read-permission":  # (as root the permission bits are not enforced: the check is what says it)
        monkeypatch.setattr(os, "access", lambda p, mode: str(p) != str(weights))
    else:
        def refuse(*a, **k):
            raise FileNotFoundError(f"No such file or directory: {weights}")
        monkeypatch.setattr(checkpoint, "load_file", refuse)
    with pytest.raises(CheckpointError) as e:
        load_checkpoint(path, model=torch.nn.Linear(3, 2))
    assert str(weights) in str(e.value) and "cannot be read" in str(e.value), str(e.value)


def test_weights_of_another_network_beside_a_json_are_refused(small_ckpt, tmp_path):
    """Another network's weights of the same shapes copied over a checkpoint's loaded silently: the JSON's fitted
    models (covariance scale, the hybrid's measurement model, the out-of-domain score) were applied to them."""
    path, _ = small_ckpt
    weights = path.with_suffix(".safetensors")
    assert len(json.loads(path.read_text())["files"]["weights_sha256"]) == 64
    load_checkpoint(path, torch.nn.Linear(3, 2))  # its own weights load
    other = save_checkpoint(tmp_path / "other" / "ckpt-0001", torch.nn.Linear(3, 2), epoch=1, model_config={"k": 1})
    weights.write_bytes(other.with_suffix(".safetensors").read_bytes())
    with pytest.raises(CheckpointError, match="is not the one this checkpoint was saved with") as e:
        load_checkpoint(path, torch.nn.Linear(3, 2))
    assert str(path) in str(e.value) and "copy the matching .safetensors" in str(e.value)
    meta = json.loads(path.read_text())
    del meta["files"]["weights_sha256"]  # a JSON without the record (older checkpoints) is not checked
    path.write_text(json.dumps(meta))
    load_checkpoint(path, torch.nn.Linear(3, 2))


@pytest.mark.parametrize("case", ["missing", "truncated-json", "pickle"])
def test_evaluate_with_a_bad_checkpoint(case, tiny, small_ckpt, tmp_path, capsys):
    path, model = small_ckpt
    if case == "missing":
        path = tmp_path / "none.json"
    elif case == "truncated-json":
        path.write_text(path.read_text()[:40])
    else:
        path = tmp_path / "model.pth"
        torch.save(model.state_dict(), path)
    argv = ["evaluate", "--data", tiny.root, "--version", VERSION, "--checkpoint", path, "--out", tmp_path / "e"]
    _expect_error(argv, capsys, path)


# ---------------------------------------------------------------- bugs and --debug
def test_a_bug_is_one_line_with_a_debug_hint(monkeypatch, tmp_path, capsys):
    import hybrid_calib.commands.simulate as simulate

    def boom(args):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(simulate, "run", boom)
    monkeypatch.delenv("HYBRID_CALIB_DEBUG", raising=False)
    err = _expect_error(["simulate", "--out", tmp_path / "s"], capsys, "internal error: ZeroDivisionError: a bug",
                        "--debug", rc=EXIT_BUG)
    assert len(err.strip().splitlines()) == 2
    with pytest.raises(ZeroDivisionError):
        main(["simulate", "--out", str(tmp_path / "s"), "--debug"])
    with pytest.raises(HybridCalibError):  # --debug re-raises expected errors too
        main(["inspect", "--data", str(tmp_path / "nowhere"), "--version", "v", "--debug"])


# ---------------------------------------------------------------- the type-checked merge
def test_check_type():
    assert check_type(True, bool) and not check_type("off", bool) and not check_type(1, bool)
    assert check_type(3, int) and not check_type(True, int) and not check_type(3.0, int)
    assert check_type(3, float) and check_type(0.5, float) and not check_type("0.5", float)
    assert check_type(None, tuple[int, ...] | None) and check_type([1, 2], tuple[int, ...] | None)
    assert not check_type([1, "a"], tuple[int, ...]) and not check_type(5, tuple[int, ...])
    assert check_type([1.0, 2], tuple[float, float]) and not check_type([1.0], tuple[float, float])
    assert check_type({"a": 1}, dict) and not check_type([1], dict[str, int])
    assert check_type(0.5, float | tuple) and check_type([1, 2], float | tuple)
    assert check_type(np.int64(2), int) and check_type(np.float32(0.5), float) and check_type(np.bool_(True), bool)
    assert not check_type(np.bool_(True), int)
    assert check_type(np.zeros(3), np.ndarray)  # classes it does not know are left alone


def test_merge_rejects_wrong_types_and_keeps_good_ones():
    from hybrid_calib.data.nuscenes import DataConfig

    conf = merge(DataConfig, {"nsweeps": 3, "scenes": ["a"], "radar_filter": {"ambig_states": None}})
    assert conf.nsweeps == 3 and conf.scenes == ("a",) and conf.radar_filter.ambig_states is None
    with pytest.raises(ConfigError, match=r"radar_filter\.enabled='no'"):
        merge(DataConfig, {"radar_filter": {"enabled": "no"}})
    assert issubclass(ConfigError, HybridCalibError) and issubclass(ConfigError, ValueError)


# ---------------------------------------------------------------- evaluate goes on past bad frames
def test_evaluate_skips_frames_with_a_corrupt_pcd_or_image(tmp_path):
    """A truncated radar PCD and a JPEG with corrupt scan data: both frames are listed in skipped.json
    (index, token, file, reason) and the other frames are evaluated."""
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.sim import simulate as sim
    from hybrid_calib.sim.drive import SimConfig
    from learned.evaluate import EvalConfig, evaluate
    from tests.test_learned_pipeline import OracleModel, oracle_exporter

    root = sim.simulate(merge(SimConfig, {"frames": 4, "image_scale": 0.125, "seed": 5}), tmp_path / "sim",
                        overwrite=False, workers=1)
    ds = NuScenesRadarCamera(root, "v1.0-sim")
    pcd = root / ds.frames[1].radar_sd["filename"]
    pcd.write_bytes(pcd.read_bytes()[:300])
    jpg = root / ds.frames[2].camera_sd["filename"]
    jpg.write_bytes(corrupt_jpeg_scan(jpg.read_bytes()))
    out = tmp_path / "eval"
    result = evaluate(OracleModel(), ds, EvalConfig(split="all"), out, exporter=oracle_exporter, progress=False)
    assert result.n_frames == 2
    skipped = json.loads((out / "skipped.json").read_text())
    assert [s["index"] for s in skipped] == [1, 2]
    assert [s["token"] for s in skipped] == [ds.frames[1].camera_sd["token"], ds.frames[2].camera_sd["token"]]
    assert [s["file"] for s in skipped] == [str(pcd), str(jpg)]
    assert "truncated PCD" in skipped[0]["reason"] and "corrupt pixel data" in skipped[1]["reason"]


def test_output_streams_that_fail_are_not_bugs(tiny, tmp_path):
    """`| head -1` and `> /dev/full` were "internal error" (exit 3), a closed stderr (`2>&-`) stopped calibrate at its
    first progress bar (probe 27)."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "PYTHONPATH": os.getcwd(), "OMP_NUM_THREADS": "1"}
    cli = [sys.executable, "-m", "hybrid_calib.cli"]
    inspect = [*cli, "inspect", "--data", str(tiny.root), "--version", VERSION, "--no-progress"]
    p = subprocess.run(f"{' '.join(inspect)} | head -c 1 > /dev/null; echo rc ${{PIPESTATUS[0]}} >&2", shell=True,
                       executable="/bin/bash", env=env, capture_output=True, text=True, timeout=300)
    assert "internal error" not in p.stderr and "Traceback" not in p.stderr, p.stderr
    if os.path.exists("/dev/full"):
        with open("/dev/full", "w") as full:
            p = subprocess.run(inspect, env=env, stdout=full, stderr=subprocess.PIPE, text=True, timeout=300)
        # said, and the run goes on (probe 119: a failing stdout stopped long runs)
        assert p.returncode == EXIT_ERROR and "its standard output cannot be written (No space left" in p.stderr, \
            p.stderr
    sim = [*cli, "simulate", "--vehicles", "1", "--frames", "3", "--set", "image_scale=0.125", "--workers", "1",
           "--out", str(tmp_path / "sim")]  # progress bars on stderr
    p = subprocess.run(sim, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, timeout=600,
                       preexec_fn=lambda: os.close(2))
    assert p.returncode == 0 and (tmp_path / "sim" / "v1.0-sim" / "sample.json").is_file(), p.stdout[-500:]


def test_a_file_where_a_folder_is_needed_is_said_so(tmp_path, capsys, monkeypatch):
    """train with a file named `checkpoints` in its run folder read "File exists [file ...]; check the path and its
    permissions" (probe 27)."""
    import hybrid_calib.commands.simulate as simulate

    blocker = tmp_path / "checkpoints"
    blocker.write_text("x")

    def mkdir(args):
        (blocker / "x").mkdir(parents=True, exist_ok=True)

    monkeypatch.setattr(simulate, "run", mkdir)
    _expect_error(["simulate", "--out", tmp_path / "s"], capsys, f"{blocker / 'x'} (or a folder above it) is a file "
                  "where a folder is needed", "move the file away")


@pytest.mark.parametrize("edit,needle", [
    (lambda m: m.pop("train_config"), "records no train_config"),
    (lambda m: m["train_config"].update(perturbation="R9"), "train_config.perturbation is 'R9', not one of"),
    (lambda m: m["train_config"].update(split="x"), "train_config.split is 'x', not an object of options"),
], ids=["no-train_config", "perturbation-R9", "split-a-string"])
def test_a_damaged_train_config_is_named_with_its_checkpoint(edit, needle, tmp_path):
    """A checkpoint without train_config ran on the simulator's true depth in silence; "R9" read as a wrong --start
    and a string split as a wrong --set (probe 109). Each is an error naming the file and the field."""
    from hybrid_calib.errors import CheckpointError
    from hybrid_calib.hybrid.network import shipped_checkpoint
    from learned.checkpoint import read_checkpoint_meta

    src = shipped_checkpoint("R1")
    meta = json.loads(src.read_text())
    edit(meta)
    path = tmp_path / src.name
    path.write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match=needle) as e:
        read_checkpoint_meta(path)
    assert str(path) in str(e.value)


def test_fitted_models_without_the_weights_hash_are_said(tmp_path):
    """Without files.weights_sha256 another network's weights under the name ran with these fitted models; the only
    symptom was "out of domain" (probe 109). It still loads (weights converted on purpose), and says so."""
    from learned.checkpoint import load_checkpoint, save_checkpoint, set_export_overrides

    path = save_checkpoint(tmp_path / "c" / "ckpt-0001", torch.nn.Linear(3, 2), epoch=1, model_config={"k": 1})
    meta = json.loads(path.read_text())
    del meta["files"]["weights_sha256"]
    path.write_text(json.dumps(meta))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_checkpoint(path, torch.nn.Linear(3, 2))  # nothing fitted: nothing to say
    set_export_overrides(path, {"cov_scale": [2.0] * 6}, "fitted by the test")
    with pytest.warns(UserWarning, match="records no files.weights_sha256.*export.cov_scale"):
        load_checkpoint(path, torch.nn.Linear(3, 2))


@pytest.mark.skipif(not hasattr(__import__("os"), "mkfifo"), reason="needs named pipes")
def test_a_named_pipe_as_the_checkpoint_is_said_as_one(tmp_path):
    """A FIFO in the checkpoint JSON's place read "checkpoint not found" (probe 109)."""
    import os

    from learned.checkpoint import read_checkpoint_meta

    os.mkfifo(tmp_path / "ckpt-0001.json")
    with pytest.raises(HybridCalibError, match="is a named pipe"):
        read_checkpoint_meta(tmp_path / "ckpt-0001.json")


def test_a_tilde_the_shell_did_not_expand_is_said_not_made_a_folder(tiny, tmp_path, capsys, monkeypatch):
    """Probe 119: --out=~/calib (bash expands ~ only at a word's start) made a folder named "~" in the working folder
    and said "wrote ~/calib/result.json", which reads as the home folder; --data '~/sim' read "does not exist"."""
    monkeypatch.chdir(tmp_path)
    expect_cli_error(["calibrate", "--data", str(tiny.root), "--version", VERSION, "--out=~/calib"], capsys,
                     "--out: ~/calib starts with '~', which the shell did not expand",
                     "pass --out ~/calib with a space")
    expect_cli_error(["inspect", "--data", "~/sim", "--version", VERSION], capsys, "--data: ~/sim starts with '~'")
    assert not (tmp_path / "~").exists()
    # a name is no path (probe 121: --radar '~a' got the path's words); a user that is not there is said so
    expect_cli_error(["inspect", "--data", str(tiny.root), "--version", VERSION, "--radar", "~a"], capsys,
                     "channel '~a' is not in sensor.json")
    expect_cli_error(["inspect", "--data", "~nosuchuser/x", "--version", VERSION], capsys,
                     "(~nosuchuser names no user here)")
    (tmp_path / "~").mkdir()  # a folder that is named so: taken as named
    assert main(["inspect", "--data", str(tiny.root), "--version", VERSION, "--out", "~/insp", "--no-progress"]) == 0
    assert (tmp_path / "~" / "insp" / "inspect_summary.json").is_file()


def test_a_name_the_file_system_encoding_cannot_hold_is_said(tmp_path, capsys, monkeypatch):
    """Probe 119: under an ASCII file-system encoding (PYTHONUTF8=0 in the C locale) a non-ASCII root named in a result
    or a fleet manifest read "does not exist" / "is not there" (it exists), and export ended in an internal error
    (UnicodeEncodeError); argv's names were already said."""
    import sys

    from hybrid_calib.cli import report_error
    from hybrid_calib.data.tables import version_dir
    from hybrid_calib.errors import DataError, unencodable_words

    assert unencodable_words(tmp_path / "données") == ""  # this process: UTF-8
    monkeypatch.setattr(sys, "getfilesystemencoding", lambda: "ascii")
    assert "file-system encoding (ascii) cannot hold: run in a UTF-8 locale (PYTHONUTF8=1)" in \
        unencodable_words(tmp_path / "données")
    assert unencodable_words(tmp_path / "plain") == ""
    with pytest.raises(DataError, match=r"nuScenes root cannot be opened; its name holds characters"):
        version_dir(tmp_path / "données", "v1.0-mini")
    assert report_error("export", UnicodeEncodeError("ascii", "/x/données", 7, 8, "ordinal not in range")) == EXIT_ERROR
    err = capsys.readouterr().err
    assert "hybrid-calib export: error: a name holds characters" in err and "internal error" not in err


def test_a_path_starting_with_a_dash_is_named(tiny, tmp_path, capsys, monkeypatch):
    """Probe 119: `export -x/result.json` read "the following arguments are required: RESULT" (one was given), `--out
    -x/y` "expected one argument", and `--out -` made a folder named "-"."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit):
        main(["export", "-x/result.json", "--out", "e"])
    assert "(-x/result.json starts with '-', so it was read as an option: write ./-x/result.json" in \
        capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["inspect", "--data", str(tiny.root), "--version", VERSION, "--out", "-x/y"])
    assert "expected one argument (-x/y starts with '-'" in capsys.readouterr().err
    expect_cli_error(["inspect", "--data", str(tiny.root), "--version", VERSION, "--out", "-"], capsys,
                     "--out: '-' (standard output or input) is not a path this command takes")
    assert not (tmp_path / "-").exists()
