"""hybrid_calib.atomic: a failed writer leaves the old file and no temporary file behind."""

import json
from pathlib import Path

import numpy as np
import pytest

from hybrid_calib.atomic import atomic_path, write_bytes_atomic
from hybrid_calib.config import save_json_atomic


def test_write_replaces_and_leaves_no_temporary(tmp_path):
    p = tmp_path / "sub" / "a.json"
    save_json_atomic(p, {"x": 1})
    save_json_atomic(p, {"x": 2})
    assert p.read_text().strip().endswith("}") and '"x": 2' in p.read_text()
    assert sorted(x.name for x in p.parent.iterdir()) == ["a.json"]


def test_failed_writer_keeps_the_old_file(tmp_path):
    p = tmp_path / "b.bin"
    write_bytes_atomic(p, b"old")
    with pytest.raises(RuntimeError), atomic_path(p) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("writer died")
    assert p.read_bytes() == b"old"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["b.bin"]


def test_temporary_keeps_the_suffix_for_format_picking_writers(tmp_path):
    p = tmp_path / "c.npz"
    with atomic_path(p) as tmp:
        assert tmp.suffix == ".npz" and tmp.parent == p.parent
        np.savez(tmp, a=np.arange(3))
    assert np.load(p)["a"].tolist() == [0, 1, 2]


def test_writer_that_writes_nothing_is_an_error(tmp_path):
    with pytest.raises(OSError, match="produced no file"), atomic_path(tmp_path / "d.png"):
        pass
    assert not (tmp_path / "d.png").exists()


def test_errors_name_the_target_not_the_temporary(tmp_path):
    """A target that is a directory is refused before the writer runs; one that becomes a directory while the
    writer works fails the rename: both errors name the target (they named result.NNNN.tmp.json)."""
    target = tmp_path / "result.json"
    target.mkdir()
    with pytest.raises(IsADirectoryError, match="result.json is a directory") as e:
        save_json_atomic(target, {"x": 1})
    assert e.value.filename == str(target)
    target.rmdir()
    with pytest.raises(IsADirectoryError, match="result.json is a directory") as e, atomic_path(target) as tmp:
        tmp.write_text("{}")
        target.mkdir()
    assert e.value.filename == str(target) and ".tmp" not in str(e.value)
    assert sorted(x.name for x in tmp_path.iterdir()) == ["result.json"] and target.is_dir()


def test_two_runs_into_one_out_folder_the_second_is_refused_naming_the_first(tmp_path):
    from hybrid_calib.atomic import LOCK_NAME, OutDirBusy, out_dir_lock

    out = tmp_path / "run"
    with out_dir_lock(out, "calibrate", argv=["calibrate", "--out", str(out)]):  # its message: the first line
        with pytest.raises(OutDirBusy, match=r"being written by another hybrid-calib run \(pid \d+, hybrid-calib "
                                             r"calibrate, since .*\); wait for it to end, or write elsewhere "
                                             r"\(another --out\)"):
            with out_dir_lock(out, "calibrate"):
                pass
        (out / "result.json").write_text("{}")
        assert (out / LOCK_NAME).exists()  # while held
    with out_dir_lock(out, "calibrate"):  # released when the first ends
        pass
    # and removed: a refused run left it in the user's data root ("refusing to write anything there")
    assert not (out / LOCK_NAME).exists() and (out / "result.json").exists()
    (out / LOCK_NAME).write_text("")  # one that was there before is left
    with out_dir_lock(out, "calibrate"):
        pass
    assert (out / LOCK_NAME).exists()
    # but not a killed run's (probe 60: every later run left it behind)
    (out / LOCK_NAME).write_text("pid 4242, hybrid-calib fleet, since 2026-12-06 04:00:00")
    with out_dir_lock(out, "fleet"):
        pass
    assert not (out / LOCK_NAME).exists()
    # a lock of any bytes is taken (probe 65: non-UTF-8 bytes were an internal error) and given back as it was, however
    # large; one with a hand-edited start is taken too
    for junk in (b"\xff\xfe not text", b"x" * 100_000,
                 b"pid 1, hybrid-calib fleet, since 2026\n" + json.dumps({"command": "fleet", "argv": ["fleet"],
                                                                         "cwd": "/", "started": 1e300}).encode()):
        (out / LOCK_NAME).write_bytes(junk)
        with out_dir_lock(out, "calibrate", argv=["calibrate"]) as recorded:
            recorded()
        assert not (out / LOCK_NAME).exists() if junk.startswith(b"pid") else (out / LOCK_NAME).read_bytes() == junk
    empty = tmp_path / "nothing"  # a folder the lock created and nothing else used is removed again
    with pytest.raises(ValueError):
        with out_dir_lock(empty, "train"):
            raise ValueError("a bad option")
    assert not empty.exists()


def test_the_lock_holds_across_processes(tmp_path, capsys):
    import subprocess
    import sys

    from hybrid_calib.cli import main

    out = tmp_path / "run"
    code = ("import sys, time; from hybrid_calib.atomic import out_dir_lock\n"
            f"with out_dir_lock({str(out)!r}, 'compare'):\n    print('held', flush=True); time.sleep(30)")
    other = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert other.stdout.readline().strip() == "held"
        assert main(["inspect", "--data", str(tmp_path / "none"), "--version", "v1.0-mini", "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert "being written by another hybrid-calib run" in err and "hybrid-calib compare" in err, err
    finally:
        other.kill()
        other.wait()


def test_a_forked_child_of_a_killed_run_does_not_hold_its_lock(tmp_path):
    """Probe 111: `simulate --workers 2` killed with -9 left its forked workers alive, and their copies of the lock's
    descriptor kept the folder locked for ever, naming the dead run. The lock's holder forks a child that outlives
    it here; the next run takes the folder; the lock of a live holder still holds (the test above)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from hybrid_calib.atomic import OutDirBusy, out_dir_lock

    out = tmp_path / "run"
    code = ("import os, signal, sys, time; from hybrid_calib.atomic import out_dir_lock\n"
            f"with out_dir_lock({str(out)!r}, 'simulate'):\n"
            "    pid = os.fork()\n"
            "    if pid == 0:\n        time.sleep(60); os._exit(0)\n"
            "    print(pid, flush=True); os.kill(os.getpid(), signal.SIGKILL)")
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    child = int(holder.stdout.readline())
    try:
        holder.wait(timeout=30)
        deadline = time.time() + 10
        while True:
            try:
                with out_dir_lock(out, "simulate"):
                    break
            except OutDirBusy:
                assert time.time() < deadline, "the killed run's child holds the lock"
                time.sleep(0.2)
    finally:
        os.kill(child, signal.SIGKILL)


@pytest.mark.parametrize("kind", ["symlink", "directory"])
def test_a_lock_path_that_is_not_a_file_is_named_and_never_followed(kind, tmp_path):
    """A symbolic link in the lock's place had its target overwritten with the lock's text; a directory there gave
    a bare 'Is a directory'."""
    from hybrid_calib.atomic import LOCK_NAME, out_dir_lock
    from hybrid_calib.errors import HybridCalibError

    out, precious = tmp_path / "run", tmp_path / "precious.txt"
    out.mkdir()
    precious.write_text("precious")
    if kind == "symlink":
        (out / LOCK_NAME).symlink_to(precious)
    else:
        (out / LOCK_NAME).mkdir()
    with pytest.raises(HybridCalibError, match=f"is a {'symbolic link' if kind == 'symlink' else 'directory'}, not "
                                               "the lock file .*remove it and rerun"):
        with out_dir_lock(out, "calibrate"):
            pass
    assert precious.read_text() == "precious"


@pytest.mark.parametrize("failure", [OSError(28, "No space left on device"),
                                     OSError("19200 requested and 13280 written")])
def test_a_full_disk_names_the_file_and_is_not_a_bug(failure, tmp_path, monkeypatch, capsys):
    """A write into the open temporary file on a full disk (no file name on the error; numpy's short write has no
    errno either) was "internal error ... looks like a bug" in every writing command (probe 27)."""
    import errno
    import os

    from hybrid_calib.cli import EXIT_ERROR, report_error

    class Full:
        f_bavail, f_frsize = 0, 4096

    monkeypatch.setattr(os, "statvfs", lambda folder: Full())
    p = tmp_path / "depth.npy"
    write_bytes_atomic(p, b"old")
    with pytest.raises(OSError) as e, atomic_path(p) as tmp:
        tmp.write_bytes(b"half")
        raise failure
    assert e.value.errno == errno.ENOSPC and e.value.filename == str(p)
    assert p.read_bytes() == b"old" and sorted(x.name for x in tmp_path.iterdir()) == ["depth.npy"]
    assert report_error("calibrate", e.value) == EXIT_ERROR
    err = capsys.readouterr().err
    assert f"no space left on the device while writing {p}" in err and "what was written before is kept" in err


@pytest.mark.parametrize("failure, free", [
    (RuntimeError("Error while serializing: I/O error: No space left on device (os error 28)"), 1 << 30),  # safetensors
    (RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 4921984 vs 4921872"), 4096),  # torch.save
])
def test_a_writer_s_own_error_on_a_full_disk_is_a_full_disk(failure, free, tmp_path, monkeypatch, capsys):
    """Probe 55: a checkpoint's weights (safetensors) or optimizer state (torch.save) on a full disk was "internal
    error ... looks like a bug", torch's naming neither the file nor the cause."""
    import errno
    import os

    from hybrid_calib.cli import EXIT_ERROR, report_error

    class Stat:
        f_bavail, f_frsize = free // 4096, 4096

    monkeypatch.setattr(os, "statvfs", lambda folder: Stat())
    p = tmp_path / "ckpt-0002.optim.pt"
    with pytest.raises(OSError) as e, atomic_path(p) as tmp:
        tmp.write_bytes(b"half")
        raise failure
    assert e.value.errno == errno.ENOSPC and e.value.filename == str(p) and not list(tmp_path.iterdir())
    assert report_error("train", e.value) == EXIT_ERROR
    assert f"no space left on the device while writing {p}" in capsys.readouterr().err
    Stat.f_bavail = 1 << 20  # the same error with room on the disk: the writer's own error, as it was
    with pytest.raises(RuntimeError, match="unexpected pos"), atomic_path(p) as tmp:
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 4921984 vs 4921872")


def test_a_short_write_with_room_on_the_disk_is_a_file_size_limit(tmp_path, capsys):
    """Probe 111: numpy's short write under `ulimit -f` (no errno) read "no space left on the device" with 74 GB
    free."""
    import errno

    from hybrid_calib.cli import report_error

    p = tmp_path / "depth.npy"
    with pytest.raises(OSError) as e, atomic_path(p) as tmp:
        tmp.write_bytes(b"half")
        raise OSError("19200 requested and 13280 written")
    assert e.value.errno == errno.EFBIG and e.value.filename == str(p)
    report_error("calibrate", e.value)
    err = capsys.readouterr().err
    assert str(p) in err and "no space left" not in err and "a file-size limit was hit" in err, err


@pytest.mark.parametrize("failure, code", [
    (RuntimeError("Error while serializing: I/O error: File too large (os error 27)"), 27),  # safetensors, ulimit -f
    (RuntimeError("[Errno 122] Disk quota exceeded"), 122),
])
def test_a_writer_s_own_system_error_names_the_file(failure, code, tmp_path, capsys):
    """Probe 111: a checkpoint under `ulimit -f` (EFBIG, in safetensors' words) was "internal error: SafetensorError"
    naming no file; every other writer says the file and the cause."""
    from hybrid_calib.cli import EXIT_ERROR, report_error

    p = tmp_path / "ckpt-0001.safetensors"
    with pytest.raises(OSError) as e, atomic_path(p) as tmp:
        tmp.write_bytes(b"half")
        raise failure
    assert e.value.errno == code and e.value.filename == str(p) and not list(tmp_path.iterdir())
    assert report_error("train", e.value) == EXIT_ERROR
    err = capsys.readouterr().err
    assert str(p) in err and "internal error" not in err, err


def test_a_lock_file_on_a_full_disk_is_named(tmp_path, monkeypatch, capsys):
    """Probe 84: on a full disk every command said "cannot write to its output" naming no file: the lock file's record
    (flushed on its write, and again on its close) raised without a file name."""
    import errno
    import os

    from hybrid_calib import atomic
    from hybrid_calib.cli import EXIT_ERROR, report_error

    real = os.fdopen

    class Full:  # the lock file's handle, on a disk with no room for its record
        def __init__(self, f):
            self.f = f

        def __getattr__(self, name):
            return getattr(self.f, name)

        def flush(self):
            raise OSError(errno.ENOSPC, "No space left on device")

        def close(self):
            self.f.close()
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(atomic.os, "fdopen", lambda fd, mode: Full(real(fd, mode)))
    with pytest.raises(OSError) as e, atomic.out_dir_lock(tmp_path / "out", "calibrate", argv=["calibrate"]):
        pass
    assert e.value.errno == errno.ENOSPC and e.value.filename == str(tmp_path / "out" / atomic.LOCK_NAME)
    assert report_error("calibrate", e.value) == EXIT_ERROR
    assert f"no space left on the device while writing {tmp_path / 'out' / atomic.LOCK_NAME}" in capsys.readouterr().err


def test_the_runs_log_appends_each_command_and_replaces_an_unreadable_one(tmp_path):
    import json
    import time

    from hybrid_calib.atomic import RUNS_NAME, record_run

    assert record_run(tmp_path / "missing", "fleet", [], 0, time.time()) is None  # no folder: nothing created
    assert not (tmp_path / "missing").exists()
    t0 = time.time()
    record_run(tmp_path, "calibrate", ["calibrate", "--data", "my root", "--out", str(tmp_path)], 0, t0)
    record_run(tmp_path, "calibrate", ["calibrate", "--data", "my root"], 2, t0)
    runs = json.loads((tmp_path / RUNS_NAME).read_text())
    assert [r["exit_status"] for r in runs] == [0, 2]
    assert runs[0]["command"] == f"hybrid-calib calibrate --data 'my root' --out {tmp_path}"  # pastes back as typed
    assert runs[0]["started_utc"].endswith("Z") and runs[0]["started_utc"] <= runs[0]["finished_utc"]
    assert {"cwd", "hybrid_calib", "python", "host"} <= set(runs[0])
    (tmp_path / RUNS_NAME).write_text("{not json")  # a log, not a record: replaced, never an error
    record_run(tmp_path, "fleet", ["fleet"], 0, t0)
    assert [r["command"] for r in json.loads((tmp_path / RUNS_NAME).read_text())] == ["hybrid-calib fleet"]


def test_a_name_derived_from_a_long_one_fits_a_file_name_and_stays_its_own():
    """Probe 66: a legal 250-character page name made its temporary file and lock too long; probe 70: the fitting
    was quadratic in the name's length."""
    import os
    import time

    from hybrid_calib.atomic import NAME_MAX, fit_name

    assert fit_name("report.html") == "report.html"
    long_a, long_b = "\u00e4" * 200 + "a.html.lock", "\u00e4" * 200 + "b.html.lock"
    for name in (long_a, long_b, "r" * 300 + ".html"):
        fitted = fit_name(name)
        assert len(os.fsencode(fitted)) <= NAME_MAX and fitted.endswith(name[-16:])
    assert fit_name(long_a) != fit_name(long_b)
    t = time.perf_counter()
    assert len(os.fsencode(fit_name("\u6f22" * 100_000))) <= NAME_MAX
    assert time.perf_counter() - t < 0.5


def test_a_killed_writer_s_temporary_file_is_known_and_removed(tmp_path):
    """Probe 90: a SIGKILL between a write and its rename left ``<stem>.<pid>.hybrid-calib-tmp<suffix>``, read as a
    frame; probe 93: a user's ``scene-0001.2.tmp.npz`` (and a frame whose token ended in ".12.tmp") is no temporary of
    ours: it is neither skipped nor deleted."""
    from hybrid_calib.atomic import finished, is_temporary, remove_temporaries

    with atomic_path(tmp_path / "a.npz") as tmp:
        assert is_temporary(tmp)
        tmp.write_bytes(b"x")
    ours = ["tok.123.hybrid-calib-tmp.npz", "ckpt-0002.optim.8772.hybrid-calib-tmp.pt", "x.99.hybrid-calib-tmp"]
    users = ["a.npz", "a.tmp.npz", "cam-0001.12.tmp.npz", "notes.17.tmp", "scene-0001.2.tmp.npz", "tok.npz", "v2.1.npz"]
    for n in ours + users:
        (tmp_path / n).write_bytes(b"x")
    assert [p.name for p in finished(sorted(tmp_path.glob("*")))] == users
    assert sorted(p.name for p in remove_temporaries(tmp_path)) == sorted(ours)
    assert sorted(p.name for p in tmp_path.iterdir()) == users
    with atomic_path(tmp_path / ("v" * 250 + ".npz")) as tmp:  # a long name keeps the mark whole
        assert is_temporary(tmp) and len(tmp.name.encode()) <= 255
        tmp.write_bytes(b"x")
    assert remove_temporaries(tmp_path / "none") == []


def test_a_damaged_run_log_is_kept_aside_not_lost(tmp_path):
    """A truncated OUT/runs.json was replaced by a new one: the history of the folder's runs was lost (probe 109)."""
    import json
    import time

    from hybrid_calib.atomic import record_run

    (tmp_path / "runs.json").write_text('[{"command": "hybrid-calib calibrate ..."')
    record_run(tmp_path, "calibrate", ["calibrate"], 0, time.time())
    assert (tmp_path / "runs.damaged.json").read_text() == '[{"command": "hybrid-calib calibrate ..."'
    assert len(json.loads((tmp_path / "runs.json").read_text())) == 1


def test_the_typed_functions_hold_their_folders_lock(tmp_path):
    """Probe 140: ``run_calibration`` (and ``compare``, ``run_fleet``, ``simulate``) took no lock: a library run and a
    ``hybrid-calib calibrate`` wrote one folder, and the command's result was replaced in silence. Each is refused
    while another process holds the folder, and goes on under a lock its own process's command holds."""
    import subprocess
    import sys

    from hybrid_calib.atomic import OutDirBusy, out_dir_lock
    from hybrid_calib.compare import compare
    from hybrid_calib.config import merge
    from hybrid_calib.fleet.driver import run_fleet
    from hybrid_calib.hybrid import run_calibration
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate
    from tests.tiny_nuscenes import VERSION, make_tiny_root

    root = make_tiny_root(tmp_path / "root", n_samples=2).root
    out = tmp_path / "run"
    code = ("import sys, time; from hybrid_calib.atomic import out_dir_lock\n"
            f"with out_dir_lock({str(out)!r}, 'calibrate'):\n    print('held', flush=True); time.sleep(60)")
    other = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    busy = r"being written by another hybrid-calib run \(pid \d+, hybrid-calib calibrate"
    try:
        assert other.stdout.readline().strip() == "held"
        calls = {"run_calibration": lambda: run_calibration(root, VERSION, out, {"method": "pure"}),
                 "compare": lambda: compare([root], VERSION, out, {"methods": ["pure"], "trials": 1}),
                 "run_fleet": lambda: run_fleet([str(root)], None, VERSION, "pure", out),
                 "simulate": lambda: simulate(merge(SimConfig, {"frames": 2}), out)}
        for name, call in calls.items():
            with pytest.raises(OutDirBusy, match=busy):
                call()
            assert sorted(p.name for p in out.iterdir()) == [".hybrid-calib.lock"], name  # nothing written
    finally:
        other.kill()
        other.wait()
    # under this process's own (the command's) lock, the function goes on; another command of this process is refused
    with out_dir_lock(out, "calibrate"):
        with out_dir_lock(out, "calibrate", reentrant=True):
            pass
        with pytest.raises(OutDirBusy):
            with out_dir_lock(out, "calibrate"):
                pass
    assert not any(out.iterdir())  # the killed holder's lock removed by the first run after it


def test_the_lock_taken_is_the_file_at_its_path(tmp_path, monkeypatch):
    """Probe 140: a holder unlinks its lock file at its end while holding it; a run that opened the file just before
    and locked it just after held a file no longer at the path, while the next run locked a new one: two holders.
    The file locked must be the one at the path (else it is opened again)."""
    import fcntl
    import os

    from hybrid_calib import atomic

    out = tmp_path / "run"
    out.mkdir()
    path = out / atomic.LOCK_NAME
    path.write_text("pid 1, hybrid-calib calibrate, since 2026-12-07 00:00:00")
    real, calls = fcntl.flock, []

    def flock_after_the_holder_left(f, op):  # the first open's file is unlinked and replaced before its flock
        calls.append(os.fstat(f.fileno()).st_ino)
        if len(calls) == 1:
            path.unlink()
            path.write_text("")
        return real(f, op)

    monkeypatch.setattr(fcntl, "flock", flock_after_the_holder_left)
    with atomic.out_dir_lock(out, "calibrate"):
        assert len(calls) == 2 and calls[1] == os.stat(path).st_ino != calls[0]


def test_a_folder_another_run_is_writing_is_not_read(tmp_path, capsys):
    """Probe 140: calibrate read a root that ``simulate --overwrite`` was re-rendering (each vanished frame blamed on a
    partial download) and a correspondence folder an evaluate was still exporting (16 of 30 frames calibrated, the
    other vehicle "not exported"). Both are refused while their writer holds them, with the writer named."""
    import subprocess
    import sys

    from hybrid_calib.cli import main
    from hybrid_calib.errors import OptionError
    from hybrid_calib.hybrid import run_calibration
    from tests.tiny_nuscenes import VERSION, make_tiny_root

    root = make_tiny_root(tmp_path / "root", n_samples=2).root
    rows = tmp_path / "rows"
    code = ("import sys, time; from hybrid_calib.atomic import out_dir_lock\n"
            f"with out_dir_lock({str(root)!r}, 'simulate'), out_dir_lock({str(rows)!r}, 'evaluate'):\n"
            "    print('held', flush=True); time.sleep(60)")
    other = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert other.stdout.readline().strip() == "held"
        free = make_tiny_root(tmp_path / "free", n_samples=2).root
        for data, argv, option, command in ((root, ["--method", "pure"], "--data", "simulate"),
                                            (free, ["--correspondences", str(rows)], "--correspondences", "evaluate")):
            assert main(["calibrate", "--data", str(data), "--version", VERSION, *argv, "--out",
                         str(tmp_path / "out")]) == 2
            err = capsys.readouterr().err
            assert f"error: {option}: " in err and "is being written by a hybrid-calib run now (pid" in err, err
            assert f"hybrid-calib {command}, since" in err and not (tmp_path / "out").exists()
        with pytest.raises(OptionError, match="is being written by a hybrid-calib run now"):
            run_calibration(root, VERSION, tmp_path / "out", {"method": "pure"})
        # a fleet manifest's roots (probe 142: only --data was checked) and a library compare of several roots
        (manifest := tmp_path / "FLEET.json").write_text(json.dumps({"roots": [str(free), str(root)]}))
        assert main(["fleet", "--manifest", str(manifest), "--version", VERSION, "--method", "pure", "--out",
                     str(tmp_path / "fleet")]) == 2
        assert f"fleet manifest {manifest}: {root} is being written" in capsys.readouterr().err
        from hybrid_calib.compare import compare

        with pytest.raises(OptionError, match=f"{root} is being written by a hybrid-calib run now"):
            compare([free, root], VERSION, tmp_path / "cmp", {"methods": ["pure"], "trials": 1})
    finally:
        other.kill()
        other.wait()


def test_the_lock_is_reentrant_in_its_own_thread_only_and_a_lockless_filesystem_is_no_writer(tmp_path, monkeypatch):
    """Probe 142: two threads of one process both went on under one lock (one result replaced in silence); a data
    root on a filesystem without flock (ENOLCK) holding a killed run's lock read as being written now."""
    import errno
    import fcntl
    import threading

    from hybrid_calib.atomic import LOCK_NAME, OutDirBusy, out_dir_lock
    from hybrid_calib.errors import check_not_being_written

    out, seen = tmp_path / "run", []

    def other_thread():
        try:
            with out_dir_lock(out, "calibrate", reentrant=True):
                seen.append("went on")
        except OutDirBusy:
            seen.append("refused")

    with out_dir_lock(out, "calibrate"):
        with out_dir_lock(out, "calibrate", reentrant=True):  # this thread: the command around the function
            t = threading.Thread(target=other_thread)
            t.start()
            t.join()
    assert seen == ["refused"]
    root = tmp_path / "root"
    root.mkdir()
    (root / LOCK_NAME).write_text("pid 99999, hybrid-calib simulate, since 2026-12-07 20:00:00")
    monkeypatch.setattr(fcntl, "flock", lambda f, op: (_ for _ in ()).throw(OSError(errno.ENOLCK, "No locks")))
    check_not_being_written(root, "--data")  # cannot tell: read as before


def test_a_result_in_a_read_only_folder_is_reused_without_the_lock(tmp_path, monkeypatch):
    """Probe 142: run_calibration on a finished result in a read-only folder (an archive) failed creating its lock
    (a raw "Read-only file system"); the reuse writes nothing, so it takes no lock."""
    import hybrid_calib.hybrid.loop as loop
    from tests.tiny_nuscenes import VERSION, make_tiny_root

    root = make_tiny_root(tmp_path / "root", n_samples=2).root
    out = tmp_path / "archive"
    out.mkdir()
    (out / "result.json").write_text("{}")
    monkeypatch.setattr(loop, "_calibrate_into", lambda *a: "reused")
    monkeypatch.setattr(loop.os, "access", lambda path, mode: Path(path) != out)
    monkeypatch.setattr(loop, "out_dir_lock", lambda *a, **k: (_ for _ in ()).throw(AssertionError("locked")))
    assert loop.run_calibration(root, VERSION, out, {"method": "pure"}) == "reused"
    with pytest.raises(AssertionError, match="locked"):  # asked to overwrite it: the lock (and its error) first
        loop.run_calibration(root, VERSION, out, {"method": "pure"}, overwrite=True)
