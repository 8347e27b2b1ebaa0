"""A run's output files published together or not at all: a staging folder and a commit journal.

``bt clean`` writes several files into one folder (``<task>.cleaned.hdf5``, ``<task>.rrd`` per
task). Each file alone is written atomically, but a run killed between two files would leave a
mix of two runs. :class:`OutputSet` prevents that::

    write every file into  DIR/.bt-staging-<pid>-<hex>/          (hidden; readers skip it)
    add DIR/bt-outputs.json, the manifest (sha256 of every output in DIR)
    write the journal      .bt-staging-…/COMMIT.json  (tmp + fsync + rename: the commit point)
    rename each file into DIR, manifest last; fsync DIR; delete the staging folder

A run killed before the journal exists is rolled back by the next run into DIR (its staging
folder is deleted); one killed after is rolled forward (the remaining renames are done). Either
way the files in DIR then all come from one run, and ``bt-outputs.json`` lists their hashes.
Temporary files of killed writers (``.<name>.tmp-<pid>-<hex>``) in DIR are removed too. A
staging folder whose process still runs is left alone, so two runs into one folder do not
interfere (the later commit wins, file by file).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import secrets
import shutil
from pathlib import Path
from types import TracebackType

from bt_pipeline.data.atomic import fsync_path, pid_alive, remove_stale_temps, temp_name
from bt_pipeline.exceptions import ConfigError

STAGING_PREFIX = ".bt-staging-"
"""Name prefix of a run's staging folder inside the output folder."""
JOURNAL = "COMMIT.json"
"""The journal in a staging folder; its presence is the run's commit point."""
MANIFEST = "bt-outputs.json"
"""The manifest in the output folder: every output's sha256, size and the run that wrote it."""

_STAGING = re.compile(re.escape(STAGING_PREFIX) + r"(?P<pid>\d{1,10})-[0-9a-f]+")
_TEMP = re.compile(r"\.(?P<name>.+)\.(tmp-\d{1,10}-[0-9a-f]+|[0-9a-f]{8,32}\.tmp)")


class OutputSet:
    """The outputs of one run into `out_dir`, published together by :meth:`commit`.

    Use as a context manager: on an exception the staged files are discarded and `out_dir` is
    left as it was.

    Example::

        with OutputSet(out_dir) as outputs:
            write_recording(outputs.path("wiping.cleaned.hdf5"), recording, overwrite=True)
            published = outputs.commit()
    """

    def __init__(self, out_dir: str | Path) -> None:
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.recovered = recover(self.out_dir)
        """What the recovery of killed runs did (one line each), for notes."""
        self.run = f"{os.getpid()}-{secrets.token_hex(6)}"
        self.staging = self.out_dir / f"{STAGING_PREFIX}{self.run}"
        self.staging.mkdir()
        self._names: list[str] = []

    def path(self, name: str) -> Path:
        """Where to write the output `name` (a plain file name) before the commit."""
        if not name or "/" in name or "\\" in name or name.startswith(".") or name == MANIFEST:
            raise ConfigError(f"output name {name!r} must be a plain, non-hidden file name")
        if name not in self._names:
            self._names.append(name)
        return self.staging / name

    def commit(self) -> list[Path]:
        """Publish every staged file (and the manifest) into the output folder; return them."""
        names = [name for name in self._names if (self.staging / name).is_file()]
        manifest = _read_manifest(self.out_dir)
        manifest = {n: e for n, e in manifest.items() if (self.out_dir / n).is_file()}
        for name in names:
            staged = self.staging / name
            manifest[name] = {
                "sha256": sha256_file(staged),
                "bytes": staged.stat().st_size,
                "run": self.run,
            }
        _write_json(self.staging / MANIFEST, {"files": manifest})
        _write_json(self.staging / JOURNAL, {"files": [*names, MANIFEST]})
        _roll_forward(self.staging, self.out_dir)
        return [self.out_dir / name for name in names]

    def discard(self) -> None:
        """Delete the staging folder and everything in it (the output folder is untouched)."""
        shutil.rmtree(self.staging, ignore_errors=True)

    def __enter__(self) -> OutputSet:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self.staging.exists() and not (self.staging / JOURNAL).exists():
            self.discard()


def recover(out_dir: Path) -> list[str]:
    """Finish or undo the runs killed while writing into `out_dir`; remove stale temp files.

    Returns:
        One line per action, naming the folder or file.
    """
    done: list[str] = []
    if not out_dir.is_dir():
        return done
    for item in sorted(out_dir.iterdir()):
        staging = _STAGING.fullmatch(item.name)
        if staging and item.is_dir():
            if pid_alive(int(staging.group("pid"))):
                continue
            if (item / JOURNAL).is_file():
                _roll_forward(item, out_dir)
                done.append(f"{item}: completed the outputs of a killed run")
            else:
                shutil.rmtree(item, ignore_errors=True)
                done.append(f"{item}: removed the partial outputs of a killed run")
            continue
        temp = _TEMP.fullmatch(item.name)
        if temp and item.is_file():
            done.extend(
                f"{p}: removed a killed writer's temporary file"
                for p in remove_stale_temps(out_dir / temp.group("name"))
            )
    return done


def verify(out_dir: Path) -> list[str]:
    """Files of `out_dir`'s manifest whose content no longer matches it (empty when all do)."""
    bad = []
    for name, entry in _read_manifest(out_dir).items():
        path = out_dir / name
        if not path.is_file() or sha256_file(path) != entry.get("sha256"):
            bad.append(name)
    return bad


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        for block in iter(lambda: file.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _roll_forward(staging: Path, out_dir: Path) -> None:
    """Do the renames the journal of `staging` lists (those left), then delete `staging`."""
    with open(staging / JOURNAL, encoding="utf-8") as file:
        names = json.load(file)["files"]
    for name in names:
        source = staging / Path(name).name
        if source.is_file():
            os.replace(source, out_dir / Path(name).name)
    if os.name == "posix":
        fsync_path(out_dir, os.O_RDONLY)
    shutil.rmtree(staging, ignore_errors=True)


def _read_manifest(out_dir: Path) -> dict[str, dict[str, object]]:
    with contextlib.suppress(OSError, ValueError):
        files = json.loads((out_dir / MANIFEST).read_text(encoding="utf-8")).get("files", {})
        if isinstance(files, dict):
            return {str(k): v for k, v in files.items() if isinstance(v, dict)}
    return {}


def _write_json(path: Path, body: object) -> None:
    """Write `body` to `path` atomically (temporary file, fsync, rename, fsync folder)."""
    tmp = temp_name(path)
    try:
        with open(tmp, "w", encoding="utf-8") as file:
            json.dump(body, file, indent=1, sort_keys=True)
            file.flush()
            os.fsync(file.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    if os.name == "posix":
        fsync_path(path.parent, os.O_RDONLY)
