"""The command line: every subcommand registers, and ``--set`` behaves the same everywhere."""

import json
import os
from pathlib import Path

import pytest

from hybrid_calib.cli import COMMANDS, build_parser

REQUIRED = {
    "simulate": ["--out", "o"],
    "demo": [],
    "inspect": ["--data", "d", "--version", "v"],
    "calibrate": ["--data", "d"],
    "train": ["--data", "d", "--out", "o"],
    "evaluate": ["--data", "d", "--checkpoint", "c", "--out", "o"],
    "report": ["r.json", "--out", "o.html"],
    "fleet": ["--data", "d", "--out", "o"],
    "compare": ["--data", "d", "--out", "o"],
    "export": ["r.json", "--out", "o"],
}
NO_CONFIG = {"export"}  # nothing to --set: its options are its flags


def test_every_registered_command_has_a_parser():
    parser = build_parser()
    assert set(REQUIRED) == set(COMMANDS)
    for name, req in REQUIRED.items():
        assert parser.parse_args([name, *req]).command == name


@pytest.mark.parametrize("name", sorted(set(REQUIRED) - NO_CONFIG))
def test_set_accepts_several_values_and_repeats(name):
    """``--set a=1 b=2 --set c=3`` keeps all three (a repeated --set must not drop earlier values)."""
    args = build_parser().parse_args([name, *REQUIRED[name], "--set", "a=1", "b=2", "--set", "c=3"])
    values = getattr(args, "set", None) or getattr(args, "overrides", None)
    assert values == ["a=1", "b=2", "c=3"]


def test_an_interrupt_says_what_was_kept_and_how_to_go_on(tmp_path, monkeypatch, capsys):
    from hybrid_calib.cli import RESUMES, main
    from hybrid_calib.commands import calibrate, report

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(calibrate, "run", interrupted)
    monkeypatch.setattr(report, "run", interrupted)
    assert main(["calibrate", "--data", str(tmp_path), "--out", str(tmp_path / "run")]) == 130
    err = capsys.readouterr().err  # nothing finished: nothing promised (it named a folder that was not there)
    assert err.strip().startswith("hybrid-calib calibrate: interrupted; it stopped before a vehicle finished, so "
                                  "no vehicle's result is kept")
    assert "cached" not in err, err  # the oracle caches nothing (probe 124: "what it cached is reused")
    assert main(["calibrate", "--data", str(tmp_path), "--method", "hybrid", "--out", str(tmp_path / "run")]) == 130
    assert "the network passes and depth it cached in --out are reused" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()  # the lock's folder, created for the run, held nothing else
    (tmp_path / "run2" / "vehicles-done").mkdir(parents=True)
    (tmp_path / "run2" / "vehicles-done" / "sim-veh-000.json").write_text("{}")
    assert main(["calibrate", "--data", str(tmp_path), "--out", str(tmp_path / "run2")]) == 130
    assert capsys.readouterr().err.strip() == f"hybrid-calib calibrate: interrupted; {RESUMES['calibrate']}"
    assert not (tmp_path / "run2" / "runs.json").exists()  # it wrote nothing: its folder is as it was

    def finished_one_then_interrupted(args):
        (args.out / "vehicles-done" / "sim-veh-001.json").write_text("{}")
        raise KeyboardInterrupt

    monkeypatch.setattr(calibrate, "run", finished_one_then_interrupted)
    assert main(["calibrate", "--data", str(tmp_path), "--out", str(tmp_path / "run2")]) == 130
    capsys.readouterr()
    # the folder's log of commands says how the run that wrote there ended (it listed only runs that returned)
    runs = json.loads((tmp_path / "run2" / "runs.json").read_text())
    assert [(r["command"].split()[1], r["exit_status"]) for r in runs] == [("calibrate", 130)]
    monkeypatch.setattr(calibrate, "run", interrupted)
    assert main(["report", str(tmp_path / "result.json"), "--out", str(tmp_path / "r.html")]) == 130
    assert capsys.readouterr().err.strip() == "hybrid-calib report: interrupted"  # nothing to resume
    assert set(RESUMES) <= set(COMMANDS)


def test_sigterm_stops_a_run_as_ctrl_c_does(tmp_path, monkeypatch, capsys):
    """Probe 47: SIGTERM (kill, timeout, docker stop, a scheduler's pre-emption) killed calibrate and fleet at once,
    exit 143 without a word, no line in runs.json and the lock left behind. Now it stops the run as Ctrl-C does: what
    was finished kept and said, the exit status recorded, the lock released; the handler is the caller's again."""
    import signal
    import time

    from hybrid_calib.atomic import LOCK_NAME
    from hybrid_calib.cli import RESUMES, main
    from hybrid_calib.commands import calibrate

    def finished_one_then_terminated(args):
        (args.out / "vehicles-done").mkdir(parents=True)
        (args.out / "vehicles-done" / "sim-veh-000.json").write_text("{}")
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises before this ends
        raise AssertionError("SIGTERM did not stop the run")

    before = signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(calibrate, "run", finished_one_then_terminated)
    assert main(["calibrate", "--data", str(tmp_path), "--out", str(tmp_path / "run")]) == 143
    assert capsys.readouterr().err.strip() == f"hybrid-calib calibrate: terminated (SIGTERM); {RESUMES['calibrate']}"
    runs = json.loads((tmp_path / "run" / "runs.json").read_text())
    assert [(r["command"].split()[1], r["exit_status"]) for r in runs] == [("calibrate", 143)]
    assert not (tmp_path / "run" / LOCK_NAME).exists()
    assert signal.getsignal(signal.SIGTERM) == before

    def terminated_inside_a_library(args):  # Ray's wait turns the handler's exception into its own KeyboardInterrupt
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
        except KeyboardInterrupt:
            raise KeyboardInterrupt from None
        raise AssertionError("SIGTERM did not stop the run")

    monkeypatch.setattr(calibrate, "run", terminated_inside_a_library)  # probe 91: "interrupted", 130
    assert main(["calibrate", "--data", str(tmp_path), "--out", str(tmp_path / "run2")]) == 143
    assert "hybrid-calib calibrate: terminated (SIGTERM)" in capsys.readouterr().err
    monkeypatch.setattr(calibrate, "run", lambda args: (_ for _ in ()).throw(KeyboardInterrupt))
    assert main(["calibrate", "--data", str(tmp_path), "--out", str(tmp_path / "run3")]) == 130  # a later Ctrl-C

    def hung_up(args):  # probe 119: the terminal or ssh session closed; the run died without its line, the lock left
        (args.out / "vehicles-done").mkdir(parents=True)
        os.kill(os.getpid(), signal.SIGHUP)
        time.sleep(5)
        raise AssertionError("SIGHUP did not stop the run")

    before = signal.getsignal(signal.SIGHUP)
    monkeypatch.setattr(calibrate, "run", hung_up)
    assert main(["calibrate", "--data", str(tmp_path), "--out", str(tmp_path / "run4")]) == 129
    assert "hybrid-calib calibrate: terminated (SIGHUP: its terminal closed; run it under nohup" in \
        capsys.readouterr().err
    assert [r["exit_status"] for r in json.loads((tmp_path / "run4" / "runs.json").read_text())] == [129]
    assert not (tmp_path / "run4" / LOCK_NAME).exists() and signal.getsignal(signal.SIGHUP) == before


def test_ctrl_c_after_a_run_finished_does_not_make_it_interrupted(tmp_path):
    """Probe 60: Ctrl-C as export ended (its outputs and runs.json written, exit status 0 recorded) made the process
    exit 130 without a word. Once the run's status is recorded, the process's own command line ends with it."""
    import subprocess
    import sys

    script = f"""
import os, signal, sys
import hybrid_calib.cli as cli
from hybrid_calib.commands import calibrate
def done(args):
    (args.out / "result.json").write_text("{{}}")
    return 0
real = cli.record_run
def record_then_interrupted(*a, **k):
    path = real(*a, **k)
    os.kill(os.getpid(), signal.SIGINT)
    return path
calibrate.run, cli.record_run = done, record_then_interrupted
sys.argv = ["hybrid-calib", "calibrate", "--data", {str(tmp_path)!r}, "--out", {str(tmp_path / "run")!r}]
sys.exit(cli.main())
"""
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    assert p.returncode == 0 and "interrupted" not in p.stderr, (p.returncode, p.stderr[-2000:])
    runs = json.loads((tmp_path / "run" / "runs.json").read_text())
    assert [r["exit_status"] for r in runs] == [0]


def _talking_calibrate(tmp_path, line: str, times: int) -> str:
    """A Python script running ``hybrid-calib calibrate`` whose command prints ``line`` ``times`` times (``k`` the
    count), writes its result.json and prints "wrote it"."""
    return f"""
import sys
import hybrid_calib.cli as cli
from hybrid_calib.commands import calibrate
def talking(args):
    for k in range({times}):
        {line}
    (args.out / "result.json").write_text("{{}}")
    print("wrote it")
    return 0
calibrate.run = talking
sys.argv = ["hybrid-calib", "calibrate", "--data", {str(tmp_path)!r}, "--out", {str(tmp_path / "run")!r}]
sys.exit(cli.main())
"""


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
def test_a_stderr_that_cannot_be_written_does_not_stop_the_run(tmp_path):
    """Probe 66: with stderr on a full disk (``2>/dev/full``) calibrate exited 1 with nothing written (its progress
    bar's write failed), its runs.json saying 2. The bars and notes are best effort; the results are written."""
    import subprocess
    import sys

    script = _talking_calibrate(tmp_path, 'print("progress " * 200, file=sys.stderr, flush=True)', 50)
    with open("/dev/full", "w") as full:
        p = subprocess.run([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=full, text=True,
                           timeout=120, env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    assert p.returncode == 0 and p.stdout == "wrote it\n", p
    assert [r["exit_status"] for r in json.loads((tmp_path / "run" / "runs.json").read_text())] == [0]


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
@pytest.mark.parametrize("where", ["a reader gone", "/dev/full"])
def test_a_stdout_that_fails_loses_only_what_it_prints(where, tmp_path):
    """Probe 119: a stdout that failed mid-run (a reader gone: `| head -1`; a full disk) stopped the run at its first
    line (fleet after one vehicle, train after one epoch), a reader gone without a word on stderr; one that failed at
    exit printed Python's "Exception ignored ... BrokenPipeError", exit 120, while runs.json said 0. The run goes on
    and writes its files; the exit status (141, or 2 for a full device) and runs.json say the output was lost."""
    import subprocess
    import sys

    script = _talking_calibrate(tmp_path, 'print(f"vehicle {k} done", flush=True)', 3)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    env.pop("PYTHONUNBUFFERED", None)
    if where == "/dev/full":
        with open("/dev/full", "w") as out:
            p = subprocess.run([sys.executable, "-c", script], stdout=out, stderr=subprocess.PIPE, text=True,
                               timeout=120, env=env)
        expect, words = 2, "its standard output cannot be written (No space left on device)"
    else:
        r, w = os.pipe()
        os.close(r)  # the reader has gone before the first line
        try:
            p = subprocess.run([sys.executable, "-c", script], stdout=w, stderr=subprocess.PIPE, text=True,
                               timeout=120, env=env)
        finally:
            os.close(w)
        expect, words = 141, "its standard output was closed by its reader"
    assert p.returncode == expect and words in p.stderr and "the run goes on" in p.stderr, (p.returncode, p.stderr)
    assert "Exception ignored" not in p.stderr and "Traceback" not in p.stderr and p.stderr.count("warning") == 1
    assert (tmp_path / "run" / "result.json").read_text() == "{}"
    assert [r["exit_status"] for r in json.loads((tmp_path / "run" / "runs.json").read_text())] == [expect]


def test_a_killed_run_is_in_runs_json_once_the_next_run_finds_its_lock(tmp_path, monkeypatch):
    """Probe 60: a run killed by SIGKILL (the OOM killer, a machine that went down) was missing from runs.json and
    its lock stayed behind; the next run into the folder now adds it, exit status null, and removes the lock."""
    import subprocess
    import sys

    from hybrid_calib.atomic import LOCK_NAME
    from hybrid_calib.cli import main
    from hybrid_calib.commands import calibrate

    out = tmp_path / "run"
    script = f"""
import os, signal, sys
import hybrid_calib.cli as cli
from hybrid_calib.commands import calibrate
def killed(args):
    (args.out / "vehicles-done").mkdir(parents=True, exist_ok=True)
    os.kill(os.getpid(), signal.SIGKILL)
calibrate.run = killed
sys.argv = ["hybrid-calib", "calibrate", "--data", {str(tmp_path)!r}, "--out", {str(out)!r}, "--seed", "3"]
sys.exit(cli.main())
"""
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    assert p.returncode == -9 and (out / LOCK_NAME).exists() and not (out / "runs.json").exists()
    monkeypatch.setattr(calibrate, "run", lambda args: 0)
    assert main(["calibrate", "--data", str(tmp_path), "--out", str(out)]) == 0
    runs = json.loads((out / "runs.json").read_text())
    assert [(r["command"].split()[-1], r["exit_status"], r["finished_utc"] is None) for r in runs] == [
        ("3", None, True), (str(out), 0, False)]
    assert runs[0]["ended"].startswith("without a word (killed") and not (out / LOCK_NAME).exists()
    # killed after its own line was written (before its lock was removed): listed once, with its own line (probe 65)
    late = script.replace("""    os.kill(os.getpid(), signal.SIGKILL)
calibrate.run = killed""", """    return 0
real = cli.record_run
def record_then_killed(*a, **k):
    real(*a, **k)
    os.kill(os.getpid(), signal.SIGKILL)
calibrate.run, cli.record_run = killed, record_then_killed""")
    assert late != script
    p = subprocess.run([sys.executable, "-c", late], capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    assert p.returncode == -9 and (out / LOCK_NAME).exists()
    assert main(["calibrate", "--data", str(tmp_path), "--out", str(out)]) == 0
    runs = json.loads((out / "runs.json").read_text())
    assert [r["exit_status"] for r in runs] == [None, 0, 0, 0], runs


def test_the_interrupt_line_comes_after_the_last_progress_bar(tmp_path, monkeypatch, capsys):
    """Probe 60: fleet's and simulate's bars were drawn once more after the interrupt's line (closed when the run's
    objects were collected): the bars still open are closed before it is printed."""
    from tqdm import tqdm

    from hybrid_calib.cli import RESUMES, main
    from hybrid_calib.commands import fleet

    held = []

    def interrupted(args):
        held.append(bar := tqdm(total=4, desc="fleet"))
        bar.update(2)
        raise KeyboardInterrupt

    monkeypatch.setattr(fleet, "run", interrupted)
    assert main(["fleet", "--data", str(tmp_path), "--out", str(tmp_path / "run")]) == 130
    assert held[0] not in getattr(tqdm, "_instances", ())  # closed, its last state drawn before the line
    err = capsys.readouterr().err
    assert err.rstrip().endswith(f"hybrid-calib fleet: interrupted; {RESUMES['fleet']}") and "fleet:  50%" in err


def test_two_reports_onto_one_page_the_second_is_refused(tmp_path, capsys):
    """Probe 60: two report runs onto one page both said "wrote" and the page held only one vehicle's."""
    from hybrid_calib.atomic import out_dir_lock
    from hybrid_calib.cli import main

    (result := tmp_path / "result.json").write_text("{}")
    page = tmp_path / "pages" / "r.html"
    with out_dir_lock(page.parent, "report", name=".r.html.lock", what=f"the page {page}"):
        assert main(["report", str(result), "--out", str(page)]) == 2
    err = capsys.readouterr().err
    assert f"the page {page} is being written by another hybrid-calib run (pid {os.getpid()}, hybrid-calib report" \
        in err and not page.exists()
    assert not any((tmp_path / "pages").iterdir()) if (tmp_path / "pages").exists() else True


def test_a_train_run_interrupted_before_its_first_checkpoint_does_not_promise_one(tmp_path, monkeypatch, capsys):
    from hybrid_calib.cli import RESUMES, main
    from hybrid_calib.commands import train

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(train, "run", interrupted)
    argv = ["train", "--data", str(tmp_path), "--out", str(tmp_path / "run")]
    assert main(argv) == 130
    assert "before its first checkpoint, so nothing is kept" in capsys.readouterr().err
    (tmp_path / "run" / "checkpoints").mkdir(parents=True)
    (tmp_path / "run" / "checkpoints" / "ckpt-0003.json").write_text("{}")
    assert main(argv) == 130
    assert capsys.readouterr().err.strip() == f"hybrid-calib train: interrupted; {RESUMES['train']}"


def test_a_warning_is_one_line(tmp_path, monkeypatch, capsys):
    """A Python warning printed our source file and line after it (``MissingSweepWarning ... frame = self[i]``)."""
    import warnings

    from hybrid_calib.cli import main
    from hybrid_calib.commands import report

    def warns(args):
        warnings.warn("RADAR_FRONT: earlier radar sweep files are absent", UserWarning, stacklevel=2)
        return 0

    monkeypatch.setattr(report, "run", warns)
    before = warnings.formatwarning
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        monkeypatch.setattr(warnings, "showwarning", lambda m, c, f, n, file=None, line=None: print(
            warnings.formatwarning(m, c, f, n, line), end="", file=__import__("sys").stderr))
        assert main(["report", str(tmp_path / "r.json"), "--out", str(tmp_path / "r.html")]) == 0
    assert capsys.readouterr().err == "warning: RADAR_FRONT: earlier radar sweep files are absent\n"
    assert warnings.formatwarning is before  # restored for whoever called main


def test_an_option_set_twice_is_refused():
    """``--set window.window=5 window.window=7`` silently took 7; ``--set window=3 window.window=5`` was an internal
    error (probe 7)."""
    from hybrid_calib.config import ConfigError, parse_overrides

    assert parse_overrides(["a.b=1", "a.c=2", "a.b=1"]) == {"a": {"b": 1, "c": 2}}  # the same item twice: harmless
    for items in (["window.window=5", "window.window=7"], ["window=3", "window.window=5"]):
        with pytest.raises(ConfigError, match="set the same option; give it once"):
            parse_overrides(items)
    # an integer past Python's conversion limit was an internal error (probe 27)
    with pytest.raises(ConfigError, match=r"window.window=9+\.\.\.\(5014 characters\)'.*does not read as a number"):
        parse_overrides(["window.window=" + "9" * 5000])
    with pytest.raises(ConfigError, match="is nested too deeply"):
        parse_overrides(["mode=" + "[" * 5000 + "]" * 5000])


def test_train_on_a_real_root_defaults_to_the_depth_calibrate_uses(tmp_path, capsys):
    """train on a real root failed every frame after loading them all ("CorruptedTruthDepth needs the simulator's
    ground-truth depth"), while calibrate picks lidar-densified there (probe 7)."""
    from hybrid_calib.commands.train import _real_root_depth
    from tests.tiny_nuscenes import VERSION, make_tiny_root

    tiny = make_tiny_root(tmp_path / "real", n_samples=2)
    assert _real_root_depth([tiny.root], VERSION) == "lidar-densified"
    assert "is a real root: training on lidar-densified depth" in capsys.readouterr().err
    (tiny.root / VERSION / "sim_vehicle.json").write_text("[]")  # a mark with no vehicle record: the dataset reads
    assert _real_root_depth([tiny.root], VERSION) == "lidar-densified"  # a real root (session 52: was "")
    log = tiny.tables["log"][0]["token"]
    (tiny.root / VERSION / "sim_vehicle.json").write_text(json.dumps({log: {"vehicle": "sim"}}))  # the simulator's
    assert _real_root_depth([tiny.root], VERSION) == ""  # mark: its own depth truth


def test_the_commands_early_choices_read_simulated_as_the_dataset_does(tmp_path):
    """Session 52: the hybrid's depth, compare's oracle check and evaluate's and train's notes tested whether
    sim_vehicle.json exists, the dataset whether it holds vehicle records: an empty or unreadable file was a simulated
    root to the first and a real one to the run."""
    import warnings

    from hybrid_calib.data.nuscenes import NuScenesRadarCamera, simulated_root
    from hybrid_calib.hybrid.drives import resolve_depth
    from hybrid_calib.hybrid.loop import HybridConfig
    from tests.tiny_nuscenes import VERSION, make_tiny_root

    tiny = make_tiny_root(tmp_path / "real", n_samples=2)
    log = tiny.tables["log"][0]["token"]
    for text, simulated in (("[]", False), ("{", False), ("{}", False), (json.dumps({log: {}}), True)):
        (tiny.root / VERSION / "sim_vehicle.json").write_text(text)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert NuScenesRadarCamera(tiny.root, VERSION).simulated is simulated, text
        assert simulated_root(tiny.root, VERSION) is simulated, text
        assert resolve_depth(tiny.root, VERSION, HybridConfig())[0] == ("" if simulated else "lidar-densified"), text
    assert simulated_root(tmp_path / "nowhere", VERSION) is False


def test_an_option_given_twice_or_an_empty_path_is_refused(tmp_path, capsys):
    """`simulate --out a --out b` wrote b alone, `--scenario highway --scenario rain` ran rain, `--out ''` read as the
    current folder (probe 27)."""
    from hybrid_calib.cli import EXIT_ERROR, main

    assert main(["simulate", "--out", str(tmp_path / "a"), "--out", str(tmp_path / "b")]) == EXIT_ERROR
    assert "--out is given twice; give it once" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    assert main(["simulate", "--scenario=highway", "--scenario", "rain", "--out", str(tmp_path / "c")]) == EXIT_ERROR
    assert "--scenario is given twice" in capsys.readouterr().err
    assert main(["simulate", "--out", ""]) == EXIT_ERROR and "--out is empty; pass a path" in capsys.readouterr().err
    # probe 40: --prior / --manifest '' read the current folder, --checkpoint '' the shipped network, RESULT '' '.'
    for argv, said in ((["fleet", "--data", str(tmp_path), "--prior", "", "--out", str(tmp_path / "f")],
                        "--prior is empty; pass a path"),
                       (["fleet", "--manifest", "", "--out", str(tmp_path / "g")], "--manifest is empty; pass a path"),
                       (["calibrate", "--data", str(tmp_path), "--checkpoint", "", "--method", "hybrid"],
                        "--checkpoint is empty; pass a path"),
                       (["inspect", "--data", str(tmp_path), "--version", ""], "--version is empty; pass a value"),
                       (["report", "", "--out", str(tmp_path / "r.html")], "an argument is empty ('')")):
        assert main(argv) == EXIT_ERROR and said in capsys.readouterr().err, argv
    assert main(["inspect", "--data", str(tmp_path), "--data", str(tmp_path), "--version", "v"]) == EXIT_ERROR
    assert "several roots go after one --data" in capsys.readouterr().err


def test_stderr_is_best_effort_in_the_command_and_in_the_fleets_workers(monkeypatch):
    """Probe 70: the fleet's spawned workers kept their raw stderr (a note there failed the job under 2>/dev/full),
    and copy.copy of the wrapper recursed."""
    import copy
    import sys

    import hybrid_calib.atomic as atomic
    import hybrid_calib.fleet.engines as engines
    from hybrid_calib.atomic import BestEffortStream

    class Full:
        def write(self, text):
            raise OSError(28, "No space left on device")

        def flush(self):
            raise OSError(28, "No space left on device")

    monkeypatch.setattr(sys, "stderr", Full())
    monkeypatch.setattr(engines, "_init_worker", lambda threads: None)
    monkeypatch.setattr(atomic, "exit_with_parent", lambda: None)
    engines._init_pool_worker(1)
    assert isinstance(sys.stderr, BestEffortStream)
    print("a note", file=sys.stderr, flush=True)  # dropped, not raised
    assert isinstance(copy.copy(sys.stderr), BestEffortStream)


def test_an_option_the_command_does_not_have_is_said_by_that_command(capsys):
    """Probe 100: `evaluate ... --no-plots` printed the top level's usage ("usage: hybrid-calib [-h] COMMAND ...",
    "hybrid-calib: error: unrecognized arguments"), unlike every other error of the command."""
    from hybrid_calib.cli import main

    with pytest.raises(SystemExit) as e:
        main(["evaluate", "--data", "x", "--checkpoint", "y", "--out", "z", "--no-plots"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "usage: hybrid-calib evaluate" in err
    assert "hybrid-calib evaluate: error: unrecognized arguments: --no-plots" in err


def test_a_version_typed_with_a_slash_is_recorded_as_the_folder_name():
    """Probe 103: `--version v1.0-sim/` (tab completion's) was recorded raw, and a rerun with `--version v1.0-sim`
    was refused as another run."""
    from hybrid_calib.cli import build_parser

    for typed in ("v1.0-sim/", "./v1.0-sim", "v1.0-sim"):
        for command in ("calibrate", "fleet", "compare", "evaluate", "train", "inspect"):
            argv = [command, "--data", "r", "--version", typed]
            argv += {"evaluate": ["--checkpoint", "c", "--out", "o"], "train": ["--out", "o"],
                     "compare": ["--out", "o"], "calibrate": ["--out", "o"], "fleet": ["--out", "o"]}.get(command, [])
            assert build_parser().parse_known_args(argv)[0].version == "v1.0-sim", (command, typed)
    assert build_parser().parse_known_args(["inspect", "--data", "r", "--version", "/abs/v"])[0].version == "/abs/v"


def test_compare_says_a_method_named_twice_is_compared_once(tmp_path, monkeypatch, capsys):
    """``--methods pure,pure-avg,pure`` compared pure once in silence (session 44's known list)."""
    from hybrid_calib import compare as compare_module
    from hybrid_calib.cli import main

    seen = {}

    def stop(data, version, out, conf, **kw):
        seen.update(conf)
        raise KeyboardInterrupt

    monkeypatch.setattr(compare_module, "compare", stop)
    main(["compare", "--data", str(tmp_path), "--out", str(tmp_path / "c"), "--methods", "pure,pure-avg, pure"])
    assert seen["methods"] == ("pure", "pure-avg")
    assert "note: --methods names pure more than once; each method is compared once" in capsys.readouterr().err
    main(["compare", "--data", str(tmp_path), "--out", str(tmp_path / "c"), "--methods", "pure,pure-avg"])
    assert "more than once" not in capsys.readouterr().err


def test_a_repeated_option_is_refused_unless_that_command_gathers_it(tmp_path, capsys):
    """calibrate / compare --refine and report --vehicle keep one value (argparse): `--refine A --refine B` ran B
    alone, `report --vehicle A --vehicle B` reported B (probe 105); evaluate's --refine, export's --vehicle and every
    --set gather every value and stay accepted."""
    from hybrid_calib.cli import EXIT_ERROR, build_parser, gathering_options, main

    for argv, name in ((["calibrate", "--data", str(tmp_path), "--refine", "a", "--refine", "shipped"], "--refine"),
                       (["compare", "--data", str(tmp_path), "--out", str(tmp_path / "c"), "--refine", "a", "--refine",
                         "b"], "--refine"),
                       (["report", str(tmp_path / "r.json"), "--vehicle", "A", "--vehicle", "B", "--out",
                         str(tmp_path / "p.html")], "--vehicle")):
        assert main(argv) == EXIT_ERROR, argv
        assert f"{name} is given twice; give it once" in capsys.readouterr().err
    # an abbreviation is the option it stands for (probe 106: --vehicle A --vehic B reported B, --out a --ou b wrote b)
    for argv, said in ((["report", str(tmp_path / "r.json"), "--vehicle", "A", "--vehic", "B", "--out",
                         str(tmp_path / "p.html")], "--vehicle is given twice (as --vehic)"),
                       (["calibrate", "--data", str(tmp_path), "--out", str(tmp_path / "a"), "--ou",
                         str(tmp_path / "b")], "--out is given twice (as --ou)")):
        assert main(argv) == EXIT_ERROR and said in capsys.readouterr().err, argv
    assert not (tmp_path / "b").exists()
    # and an abbreviated gathering option gathers (it was refused as given twice)
    main(["export", str(tmp_path / "r.json"), "--out", str(tmp_path / "e"), "--veh", "A", "--veh", "B"])
    assert "given twice" not in capsys.readouterr().err
    parser = build_parser()
    commands = {a.dest: a for a in parser._actions if isinstance(a.choices, dict)}
    sub = next(iter(commands.values())).choices
    assert {"--set", "--refine"} <= gathering_options(sub["evaluate"])
    assert "--vehicle" in gathering_options(sub["export"])
    assert "--no-plots" in gathering_options(sub["calibrate"])  # a flag twice loses nothing (probe 107)
    assert "--refine" not in gathering_options(sub["calibrate"]) and "--vehicle" not in gathering_options(sub["report"])


def test_the_compare_api_refuses_a_method_named_twice():
    """``compare(..., {"methods": ["pure", "pure"]})`` recorded the duplicate and listed its trials twice (probe 106);
    the command dedupes and says so (above), the config refuses it."""
    from hybrid_calib.compare import CompareConfig
    from hybrid_calib.config import merge

    with pytest.raises(ValueError, match="names pure more than once"):
        merge(CompareConfig, {"methods": ["pure", "hybrid", "pure"]})
    assert merge(CompareConfig, {"methods": ["pure", "hybrid"]}).methods == ("pure", "hybrid")


def test_a_deleted_working_folder_is_said_in_one_line(tmp_path):
    """Probe 111: run from a folder deleted under the shell, every command taking --out ended in "internal error:
    FileNotFoundError" (the lock records the working folder) and report in an MKL fatal error (torch loads from it)."""
    import subprocess
    import sys

    repo = Path(__file__).resolve().parents[1]
    code = "from hybrid_calib.cli import main; raise SystemExit(main(['inspect', '--data', '/nonexistent', " \
           f"'--version', 'v1.0-mini', '--out', {str(tmp_path / 'out')!r}]))"
    gone = tmp_path / "gone"
    script = f"mkdir {gone} && cd {gone} && rmdir {gone} && exec {sys.executable} -c \"{code}\""
    run = subprocess.run(["bash", "-c", script], capture_output=True, text=True, env={**os.environ,
                         "PYTHONPATH": str(repo)}, timeout=120)
    assert run.returncode == 2, run.stderr
    assert "the working folder no longer exists" in run.stderr and "internal error" not in run.stderr, run.stderr


def test_a_dataloader_worker_ended_by_the_groups_signal_stops_the_run_as_that_signal(capsys):
    """Probe 111: `train` with DataLoader workers, SIGTERM sent to the process group (docker stop, systemd): the worker
    died first and torch's RuntimeError read "internal error" (exit 3), or an 18-line traceback from the loader's
    __del__ came before the "terminated" line."""
    import signal
    from types import SimpleNamespace

    from hybrid_calib.cli import Terminated, _on_sigterm, _quiet_stopped_workers
    from hybrid_calib.errors import stop_signal_of
    from learned.train import _stopped_workers_stop_the_run

    killed = RuntimeError("DataLoader worker (pid 19026) is killed by signal: Terminated. ")
    assert stop_signal_of(killed) == signal.SIGTERM
    assert stop_signal_of(RuntimeError("DataLoader worker (pid 5) is killed by signal: Interrupt. ")) == signal.SIGINT
    assert stop_signal_of(RuntimeError("DataLoader worker (pid 5) is killed by signal: Segmentation fault. ")) is None
    before = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        with pytest.raises(Terminated), _stopped_workers_stop_the_run():
            raise killed
        with pytest.raises(RuntimeError, match="Segmentation"), _stopped_workers_stop_the_run():
            raise RuntimeError("DataLoader worker (pid 5) is killed by signal: Segmentation fault. ")
    finally:
        signal.signal(signal.SIGTERM, before)
    _quiet_stopped_workers(SimpleNamespace(exc_value=killed, exc_type=RuntimeError, exc_traceback=None,
                                           err_msg=None, object=None))
    assert capsys.readouterr().err == ""


def test_an_interrupt_raised_inside_a_del_still_stops_the_run(capsys):
    """Probe 124: a Ctrl-C whose KeyboardInterrupt was raised inside a weakref callback was printed as "Exception
    ignored in: ... KeyboardInterrupt" and dropped: the fleet wrote every page and exited 0. SIGTERM's Terminated the
    same. The command's unraisable hook delivers it again, and says nothing."""
    import signal
    import sys

    from hybrid_calib import cli

    class Dies:
        def __init__(self, error):
            self.error = error

        def __del__(self):
            raise self.error

    before, handler = sys.unraisablehook, signal.signal(signal.SIGTERM, cli._on_sigterm)
    # Python's own Ctrl-C handler (a shell's background job starts with SIGINT ignored, which keeps a process from
    # having one: then no Ctrl-C reaches it at all, and there is nothing to deliver again)
    sigint = signal.signal(signal.SIGINT, signal.default_int_handler)
    sys.unraisablehook = cli._quiet_stopped_workers
    try:
        with pytest.raises(KeyboardInterrupt) as got:
            Dies(KeyboardInterrupt())
            for _ in range(10 ** 7):  # the signal delivered again lands at a bytecode boundary
                pass
        assert type(got.value) is KeyboardInterrupt
        cli._SIGTERM_SEEN[0] = signal.SIGTERM
        with pytest.raises(cli.Terminated):
            Dies(cli.Terminated())
            for _ in range(10 ** 7):
                pass
        sys.unraisablehook, cli._SIGTERM_SEEN[0] = cli._interrupts_stop_the_run, 0  # --debug's (probe 127)
        with pytest.raises(KeyboardInterrupt):
            Dies(KeyboardInterrupt())
            for _ in range(10 ** 7):
                pass
    finally:
        sys.unraisablehook, cli._SIGTERM_SEEN[0] = before, 0
        signal.signal(signal.SIGTERM, handler)
        signal.signal(signal.SIGINT, sigint)
    assert "Exception ignored" not in capsys.readouterr().err


def test_a_name_the_terminal_cannot_show_is_shown_escaped(tmp_path):
    """Probe 119: PYTHONIOENCODING=ascii (legacy job runners) made "wrote 数据/result.json" an internal error (exit
    3), the files complete."""
    import subprocess
    import sys

    script = _talking_calibrate(tmp_path, 'print("wrote 数据/result.json", flush=True)', 1)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]), "PYTHONIOENCODING": "ascii"}
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=env)
    assert p.returncode == 0 and "wrote \\u6570\\u636e/result.json" in p.stdout, (p.returncode, p.stderr)


def test_inner_progress_bars_end_their_line_in_a_log(monkeypatch):
    """Probe 119: off a terminal, train's per-epoch bars (leave=False) ended only in carriage returns: a night's log
    was one line. They are left (a line each) off a terminal and cleared on one."""
    import sys

    from hybrid_calib.atomic import leave_bars

    class Stream:
        def __init__(self, tty):
            self.tty = tty

        def isatty(self):
            return self.tty

    monkeypatch.setattr(sys, "stderr", Stream(False))
    assert leave_bars() is True
    monkeypatch.setattr(sys, "stderr", Stream(True))
    assert leave_bars() is False


def test_a_run_under_nohup_outlives_its_terminal(tmp_path):
    """The SIGHUP handler (probe 119) is not installed where SIGHUP is ignored (nohup): the run goes on."""
    import subprocess
    import sys

    hang_up = "import os, signal, time; os.kill(os.getpid(), signal.SIGHUP); time.sleep(0.2)"
    script = _talking_calibrate(tmp_path, hang_up, 1)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    p = subprocess.run(["nohup", sys.executable, "-c", script], capture_output=True, text=True, timeout=120, env=env,
                       cwd=tmp_path)
    assert p.returncode == 0 and (tmp_path / "run" / "result.json").is_file(), (p.returncode, p.stderr)


def test_the_uncertainty_fit_refuses_a_real_root_whatever_its_folder_is_named(tmp_path):
    """Probe 141: ``--fit-uncertainty`` tested the version folder's name: real tables in a folder named v1.0-sim were
    fitted as the truth (yaw scale x11.5 written into the checkpoint) while the same run said the root "holds no
    simulator truth"; a simulated root in a folder of another name was refused as real."""
    import shutil

    from hybrid_calib.errors import HybridCalibError
    from learned.uncertainty_fit import check_fit
    from tests.tiny_nuscenes import VERSION, make_tiny_root

    tiny = make_tiny_root(tmp_path / "real", n_samples=2)
    shutil.move(tiny.root / VERSION, tiny.root / "v1.0-sim")
    with pytest.raises(HybridCalibError, match=r"real root \(no simulator truth"):
        check_fit(tmp_path / "no-checkpoint.safetensors", [tiny.root], "val", "v1.0-sim", refine=False)
    log = tiny.tables["log"][0]["token"]
    (tiny.root / "v1.0-sim" / "sim_vehicle.json").write_text(json.dumps({log: {}}))  # simulated, any folder name
    shutil.move(tiny.root / "v1.0-sim", tiny.root / "drives")
    with pytest.raises(Exception) as refused:  # past the real-root test: the (absent) checkpoint is read next
        check_fit(tmp_path / "no-checkpoint.safetensors", [tiny.root], "val", "drives", refine=False)
    assert "real root" not in str(refused.value)


@pytest.mark.parametrize("text", ['[{"log_token": ["x"]}]', '{"vehicles": [{"log_token": {"a": 1}}]}',
                                  '[{"vehicle": "no token"}]'])
def test_a_sim_vehicle_record_without_a_log_token_string_is_named(tmp_path, capsys, text):
    """Probe 142: a list-form sim_vehicle.json whose log_token was a list or a dict was an internal error
    ("unhashable type") in calibrate and compare; records without one all read as the log None."""
    from hybrid_calib.cli import main
    from tests.tiny_nuscenes import VERSION, make_tiny_root

    tiny = make_tiny_root(tmp_path / "root", n_samples=2)
    (tiny.root / VERSION / "sim_vehicle.json").write_text(text)
    assert main(["calibrate", "--data", str(tiny.root), "--version", VERSION, "--method", "pure", "--out",
                 str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "sim_vehicle.json record 0 has no log_token string" in err and "internal error" not in err, err
