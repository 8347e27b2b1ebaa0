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

A set may span several folders (``bt evaluate --plots A --rollouts-out B --rrd C/x.rrd``):
``path(name, folder)`` stages into ``folder/.bt-staging-<run>/`` (same file system as its
destination, so the renames stay atomic), which holds ``PRIMARY.json`` naming the first
folder's staging folder. The one journal, in that primary staging folder, lists the others::

    commit point   primary journal written (it names every secondary staging folder)
    roll forward   each secondary's files renamed into its folder, secondary deleted; then the
                   primary's files; primary deleted last
    roll back      secondaries deleted first, then the primary

So a secondary whose primary holds a journal is rolled forward by the next run into its folder,
and one whose primary is gone or holds no journal is rolled back.
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
PRIMARY = "PRIMARY.json"
"""In a secondary staging folder: the path of the set's primary staging folder."""
_INTERNAL = (JOURNAL, MANIFEST, PRIMARY)

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
        self._stagings: dict[Path, Path] = {self.out_dir.resolve(): self.staging}

    def path(self, name: str, folder: str | Path | None = None) -> Path:
        """Where to write the output `name` (a plain file name) of `folder` (default: the
        set's output folder) before the commit."""
        if not name or "/" in name or "\\" in name or name.startswith(".") or name in _INTERNAL:
            raise ConfigError(f"output name {name!r} must be a plain, non-hidden file name")
        return self.staging_of(folder) / name

    def staging_of(self, folder: str | Path | None = None) -> Path:
        """The staging folder of `folder` (created, after recovering `folder`, on first use):
        every plain file a writer puts there is published into `folder` by :meth:`commit`."""
        if folder is None:
            return self.staging
        key = Path(folder).resolve()
        if key not in self._stagings:
            key.mkdir(parents=True, exist_ok=True)
            self.recovered += recover(key)
            staging = key / self.staging.name
            staging.mkdir()
            _write_json(staging / PRIMARY, {"primary": str(self.staging.resolve())})
            self._stagings[key] = staging
        return self._stagings[key]

    def commit(self) -> list[Path]:
        """Publish every staged file (and a manifest per folder) into its folder; return them."""
        published: list[Path] = []
        journal: dict[str, object] = {"folders": {}}
        for folder, staging in self._stagings.items():
            names = _staged_names(staging)
            manifest = _read_manifest(folder)
            manifest = {n: e for n, e in manifest.items() if (folder / n).is_file()}
            for name in names:
                staged = staging / name
                manifest[name] = {
                    "sha256": sha256_file(staged),
                    "bytes": staged.stat().st_size,
                    "run": self.run,
                }
            _write_json(staging / MANIFEST, {"files": manifest})
            if staging == self.staging:
                journal["files"] = [*names, MANIFEST]
            else:
                journal["folders"][str(folder)] = str(staging)  # type: ignore[index]
            published += [folder / name for name in names]
        _write_json(self.staging / JOURNAL, journal)
        _roll_forward(self.staging, self.out_dir)
        return published

    def discard(self) -> None:
        """Delete the staging folders (secondaries first) and everything in them; the output
        folders are untouched."""
        for staging in self._stagings.values():
            if staging != self.staging:
                shutil.rmtree(staging, ignore_errors=True)
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
            elif (item / PRIMARY).is_file() and _primary_committed(item):
                _publish(item, out_dir, [*_staged_names(item), MANIFEST])
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
    """Do the renames the journal of `staging` lists (those left): the other folders' first,
    then this folder's; then delete `staging`."""
    with open(staging / JOURNAL, encoding="utf-8") as file:
        journal = json.load(file)
    for folder, secondary in journal.get("folders", {}).items():
        secondary = Path(secondary)
        if secondary.is_dir():
            _publish(secondary, Path(folder), [*_staged_names(secondary), MANIFEST])
    _publish(staging, out_dir, journal["files"])


def _publish(staging: Path, out_dir: Path, names: list[str]) -> None:
    """Rename `names` (those left) from `staging` into `out_dir`, fsync it, delete `staging`."""
    for name in names:
        source = staging / Path(name).name
        if source.is_file():
            os.replace(source, out_dir / Path(name).name)
    if os.name == "posix":
        fsync_path(out_dir, os.O_RDONLY)
    shutil.rmtree(staging, ignore_errors=True)


def _staged_names(staging: Path) -> list[str]:
    """The outputs in a staging folder: its plain, visible files but the set's own."""
    return sorted(
        p.name
        for p in staging.iterdir()
        if p.is_file() and not p.name.startswith(".") and p.name not in _INTERNAL
    )


def _primary_committed(secondary: Path) -> bool:
    """Whether the primary staging folder named in `secondary` holds its journal."""
    with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
        primary = json.loads((secondary / PRIMARY).read_text(encoding="utf-8"))["primary"]
        return (Path(primary) / JOURNAL).is_file()
    return False


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
