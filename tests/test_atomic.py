"""hybrid_calib.atomic: a failed writer leaves the old file and no temporary file behind."""

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
