"""The driver's per-file fast paths give pathlib's answers (issue 47 item 4: a JPEG folder holds a file a frame).

`fingerprint_files`, `RealPaths` and the checksum names take plain paths through string operations and one
lstat; each is compared here with the pathlib code it replaced, on a tree made to trip string shortcuts:
names whose string order differs from Path order ("a.b/c" vs "a/b"), a symlink inside the tree, a folder
reached through a symlink, a relative root, paths with "//" and "/./", a file outside the tree, a FIFO.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest

from htdata.errors import EpisodeError
from htdata.source.adapters.discovery import fingerprint_files
from htdata.source.adapters.sourcetree import RealPaths, check_source_file, plain_path, real_path


def reference_fingerprint(root, files) -> str:
    """fingerprint_files as it was before the fast path (pathlib throughout)."""
    h = hashlib.sha1()
    root = Path(root)
    folders: dict = {}
    for path in sorted(Path(p) for p in files):
        check_source_file(path, root, folders)
        st = path.stat()
        try:
            rel = path.relative_to(root).as_posix()
        except ValueError:
            rel = path.as_posix()
        h.update(f"{rel}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


@pytest.fixture
def tree(tmp_path) -> Path:
    root = tmp_path / "src"
    for rel in ("a/b", "a.b/c", "a-b/x", "a/b.jpg", "a/0002.jpg", "a/0010.jpg", "z/frame_1.JPG", "deep/er/f"):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(rel.encode())
    (root / "link.jpg").symlink_to(root / "a" / "b.jpg")
    (root / "linked_dir").symlink_to(root / "deep")
    (tmp_path / "outside.jpg").write_bytes(b"o")
    (root / "escape.jpg").symlink_to(tmp_path / "outside.jpg")
    return root


def _files(root: Path) -> list[str]:
    return [str(root / r) for r in ("a/b", "a.b/c", "a-b/x", "a/b.jpg", "a/0010.jpg", "a/0002.jpg",
                                     "z/frame_1.JPG", "deep/er/f", "link.jpg", "linked_dir/er/f")]


def test_fingerprint_matches_pathlib_on_plain_odd_and_linked_paths(tree, monkeypatch):
    files = _files(tree)
    assert fingerprint_files(tree, files) == reference_fingerprint(tree, files)
    assert fingerprint_files(tree, [Path(f) for f in reversed(files)]) == reference_fingerprint(tree, files)
    odd = [f.replace("/a/", "//a/") for f in files[:3]] + [f.replace("/z/", "/./z/") for f in files[6:7]]
    assert fingerprint_files(tree, odd) == reference_fingerprint(tree, odd)       # not plain: pathlib's way
    monkeypatch.chdir(tree.parent)                                                  # a relative root and files
    rel = [os.path.relpath(f, tree.parent) for f in files]
    assert fingerprint_files(Path("src"), rel) == reference_fingerprint(Path("src"), rel)
    assert fingerprint_files(tree, rel) == reference_fingerprint(tree, rel)         # relative files, absolute root
    assert fingerprint_files(tree, files[:2] + rel[2:]) == reference_fingerprint(tree, files[:2] + rel[2:])


def test_fingerprint_refuses_what_check_source_file_refuses(tree):
    """The fast path never accepts a file the rules refuse: the same error as before, for the same file."""
    os.mkfifo(tree / "a" / "pipe.jpg")
    for bad in (tree / "escape.jpg", tree / "a" / "pipe.jpg", tree / "a" / "missing.jpg", tree / "a",
                tree.parent / "outside.jpg"):
        files = _files(tree) + [str(bad)]
        with pytest.raises(EpisodeError) as ours:
            fingerprint_files(tree, files)
        with pytest.raises(EpisodeError) as ref:
            reference_fingerprint(tree, files)
        assert str(ours.value) == str(ref.value)


def test_real_paths_match_real_path(tree, monkeypatch):
    real = RealPaths()
    names = _files(tree) + [str(tree / "escape.jpg"), str(tree / "a" / "missing.jpg"), str(tree / "a//b"),
                            str(tree) + "/./a/b", "/", str(tree / "a") + "/"]
    for name in names + names:                                       # the second pass: cached answers
        assert real(name) == str(real_path(Path(name), {})), name
    monkeypatch.chdir(tree)
    for name in ("a/b", "link.jpg", "linked_dir/er/f", "b"):
        assert RealPaths()(name) == str(real_path(Path(name), {})), name


def test_checksum_names_match_relative_to(tree):
    from htdata.ingest.sourcesums import _Names

    names = _Names(RealPaths())
    for path in _files(tree) + [str(tree / "a//b"), "/elsewhere/x", str(tree) + "x/y"]:
        try:
            rel = Path(path).relative_to(tree).as_posix()
        except ValueError:
            rel = str(path)
        assert names(path, tree) == (str(real_path(Path(path), {})), rel), path
    assert names("/x/y", Path("/"))[1] == "x/y"


@pytest.mark.parametrize("text, plain", [("/a/b", True), ("a/b", True), ("a", True), ("/", False), ("", False),
                                         (".", False), ("a//b", False), ("a/./b", False), ("a/", False),
                                         ("./a", False), ("a/.", False), ("a/../b", True)])
def test_plain_path_is_what_pathlib_writes(text, plain):
    assert plain_path(text) is plain
    if plain:
        assert str(Path(text)) == text
