"""Folders below a root reached without following a link anywhere on the way (`corelib.nolinks`; issue 49, item 1:
O_NOFOLLOW on the last component let a clean-up delete through a linked ``runs/`` folder)."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from corelib.atomic import LinkRefused
from corelib.nolinks import linked_part, open_folder, write_json_in


@pytest.fixture
def tree(tmp_path):
    """root/a/b/c, and outside/b/c with a file in it."""
    root, outside = tmp_path / "root", tmp_path / "outside"
    (root / "a" / "b" / "c").mkdir(parents=True)
    (outside / "b" / "c").mkdir(parents=True)
    (outside / "b" / "c" / "f.json").write_text("{}")
    return root, outside


def test_a_folder_without_links_opens_and_a_missing_one_is_made_only_when_asked(tree):
    root, _ = tree
    fd = open_folder(root, root / "a" / "b" / "c")
    try:
        assert os.path.samestat(os.fstat(fd), os.stat(root / "a" / "b" / "c"))
    finally:
        os.close(fd)
    with pytest.raises(FileNotFoundError) as e:
        open_folder(root, "a/x/y")
    assert e.value.filename == str(root / "a" / "x") and not (root / "a" / "x").exists()
    os.close(open_folder(root, "a/x/y", create=True))
    assert (root / "a" / "x" / "y").is_dir()
    assert linked_part(root, root / "a" / "b" / "c") is None and linked_part(root, "a/new/deeper") is None


@pytest.mark.parametrize("at", ["a", "a/b", "a/b/c"])
def test_a_link_at_any_level_is_refused_naming_it(tree, at):
    root, outside = tree
    import shutil

    shutil.rmtree(root / at)
    target = outside if at == "a" else outside / "b" if at == "a/b" else outside / "b" / "c"
    (root / at).symlink_to(target, target_is_directory=True)
    path = root / "a" / "b" / "c"
    assert linked_part(root, path) == root / at
    with pytest.raises(LinkRefused) as e:
        open_folder(root, path)
    assert e.value.filename == str(root / at)
    with pytest.raises(LinkRefused):
        write_json_in(root, path / "f.json", {"written": True})
    assert json.loads((outside / "b" / "c" / "f.json").read_text()) == {}
    assert sorted(p.name for p in (outside / "b" / "c").iterdir()) == ["f.json"]  # no temporary file left there


def test_the_root_itself_may_be_a_link(tree, tmp_path):
    root, _ = tree
    alias = tmp_path / "alias"
    alias.symlink_to(root, target_is_directory=True)
    write_json_in(alias, alias / "a" / "b" / "c" / "g.json", {"n": 1})
    assert json.loads((root / "a" / "b" / "c" / "g.json").read_text()) == {"n": 1}
    assert linked_part(alias, alias / "a" / "b") is None


def test_a_path_outside_the_root_is_an_error(tree):
    root, outside = tree
    with pytest.raises(ValueError, match="is not inside"):
        open_folder(root, outside / "b")
    with pytest.raises(ValueError, match="is not inside"):
        open_folder(root, "a/../../outside")


def test_a_path_given_as_the_caller_names_it_is_written_once_not_below_the_root_again(tree, monkeypatch):
    """A sweep names its folder relative to the working directory (``sweeps/x``) and a run's record below it
    (``sweeps/x/runs/r/status.json``): the record lands there, not in ``sweeps/x/sweeps/x/runs/...``, and a path
    relative to the root still means one below it."""
    root, _ = tree
    monkeypatch.chdir(root.parent)
    rel_root = Path(root.name)
    write_json_in(rel_root, rel_root / "a" / "status.json", {"n": 2})
    assert json.loads((root / "a" / "status.json").read_text()) == {"n": 2}
    assert not (root / root.name).exists()
    write_json_in(rel_root, Path("a") / "b" / "other.json", {"n": 3})
    assert json.loads((root / "a" / "b" / "other.json").read_text()) == {"n": 3}
