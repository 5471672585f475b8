"""Open, test and list files under a local path or an fsspec URL.

Readers accept "/data/ds", "file:///data/ds", "memory://ds", "s3://bucket/ds".
Local paths use the builtin `open` (fastest seek+read); anything with a
protocol goes through fsspec. Dataset writers are local-only; `htdata publish`
(htdata/store/remote.py) uploads a committed dataset with `url_to_fs`.
"""

from __future__ import annotations

import os
import posixpath
from pathlib import Path
from typing import IO

from htdata.errors import BackendMissing

# fsspec protocols whose backend is a separate package -> (package, htdata extra that installs it)
BACKENDS = {"s3": ("s3fs", "s3"), "s3a": ("s3fs", "s3"), "gs": ("gcsfs", "gcs"), "gcs": ("gcsfs", "gcs"),
            "az": ("adlfs", "azure"), "abfs": ("adlfs", "azure"), "abfss": ("adlfs", "azure")}


CACHE_ENV = "HTDATA_CACHE"


def cache_dir() -> Path:
    """This machine's cache of derived files (a remote index, an assembled one): $HTDATA_CACHE, else ~/.cache/htdata."""
    env = os.environ.get(CACHE_ENV)
    return Path(env) if env else Path.home() / ".cache" / "htdata"


def is_url(location: str | os.PathLike) -> bool:
    """True when `location` has a protocol other than plain local files."""
    text = os.fspath(location)
    return "://" in text and not text.startswith("file://")


def _local(location: str | os.PathLike) -> str:
    text = os.fspath(location)
    return text.removeprefix("file://")


def join(root: str | os.PathLike, *parts: str) -> str:
    """Join path parts with "/" for URLs and os.path for local paths."""
    if is_url(root):
        return posixpath.join(os.fspath(root).rstrip("/"), *parts)
    return os.path.join(_local(root), *parts)


# protocols whose backend needs more than a Python package, and what (said when it fails to start)
NATIVE_NEEDS = {"hdfs": "a Java runtime and Hadoop's libhdfs, loaded by pyarrow (set JAVA_HOME and HADOOP_HOME)",
                "webhdfs": "a reachable WebHDFS name node"}


def url_to_fs(location: str):
    """(fsspec filesystem, path inside it) for a URL; a backend that is missing, or fails to start (hdfs://
    without a JVM), raises BackendMissing (one line)."""
    import fsspec

    try:
        return fsspec.core.url_to_fs(location)
    except ImportError as exc:
        raise BackendMissing(missing_backend_message(location, exc)) from None
    except OSError as exc:   # e.g. pyarrow's HDFS: a multi-line dlopen report when no JVM is found
        raise BackendMissing(unusable_backend_message(location, exc)) from None


def missing_backend_message(location: str, exc: ImportError) -> str:
    """`location`: what to install for its protocol (fsspec's own hint for protocols not in BACKENDS)."""
    protocol = os.fspath(location).split("://", 1)[0].lower()
    if protocol in BACKENDS:
        package, extra = BACKENDS[protocol]
        return (f"{location}: {protocol}:// needs the {package} package, which is not installed: "
                f"pip install {package} (or htdata's extra: pip install '.[{extra}]' in the htdata checkout)")
    return f"{location}: {protocol}:// needs a package that is not installed: {exc}"


def unusable_backend_message(location: str, exc: OSError) -> str:
    """`location`: its protocol's filesystem could not start; what it needs, and the error's first line."""
    protocol = os.fspath(location).split("://", 1)[0].lower()
    first = next((line.strip() for line in str(exc).splitlines() if line.strip()), type(exc).__name__)
    need = NATIVE_NEEDS.get(protocol)
    return (f"{location}: the {protocol}:// filesystem could not start: {first}"
            + (f"; {protocol}:// needs {need}" if need else ""))


def open_binary(location: str | os.PathLike) -> IO[bytes]:
    """Open a file for binary reading (seekable)."""
    if not is_url(location):
        return open(_local(location), "rb")
    fs, path = url_to_fs(os.fspath(location))
    return fs.open(path, "rb")


def read_bytes(location: str | os.PathLike) -> bytes:
    with open_binary(location) as f:
        return f.read()


def read_text(location: str | os.PathLike) -> str:
    return read_bytes(location).decode("utf-8")


def exists(location: str | os.PathLike) -> bool:
    if not is_url(location):
        return os.path.exists(_local(location))
    fs, path = url_to_fs(os.fspath(location))
    return fs.exists(path)


def listdir(location: str | os.PathLike) -> list[str]:
    """Sorted base names of the entries of a directory."""
    if not is_url(location):
        return sorted(os.listdir(_local(location)))
    fs, path = url_to_fs(os.fspath(location))
    return sorted(posixpath.basename(p.rstrip("/")) for p in fs.ls(path, detail=False))


def local_path(location: str | os.PathLike) -> Path | None:
    """The local Path for a local location, None for a remote URL."""
    return None if is_url(location) else Path(_local(location))
