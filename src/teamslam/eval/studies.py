"""The runs of a study, kept one file each as they finish, so that ``--resume`` runs the rest.

A :class:`RunStore` is a folder (``<out>/runs`` of ``teamslam montecarlo``, ``<out>/tasks`` of
``teamslam paper``) holding ``study.json`` — what every run depends on: the study's settings
and teamslam's version — and one file per finished run, each written atomically (a partial file
never takes a run's name), so an interrupted study keeps every run that finished. A study
started again without ``resume`` replaces the stored runs as its own come in; with ``resume``
it reads them back and runs only the missing ones, and a folder whose ``study.json`` differs
from the study is refused (one line naming the first setting that differs), never mixed in.
A run read back is the run written (arrays bit for bit), so a resumed study gives the same
result as one run at once.
"""

from __future__ import annotations

import json
import pickle
import re
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import Any

import numpy as np

from teamslam.errors import InputError
from teamslam.eval.outputs import json_safe, write_json, writing
from teamslam.msckf.team import write_atomic
from teamslam.textio import open_npz

__all__ = [
    "STUDY_FILE",
    "RunStore",
    "load_arrays",
    "load_pickle",
    "save_arrays",
    "save_pickle",
]

#: What the stored runs are runs of.
STUDY_FILE = "study.json"


def save_arrays(path: Path, result: dict[str, dict[str, np.ndarray]]) -> None:
    """A run's ``{group: {name: array}}`` as one ``.npz`` (keys ``group/name``)."""
    flat = {f"{group}/{name}": a for group, arrays in result.items() for name, a in arrays.items()}
    with path.open("wb") as f:
        np.savez(f, **flat)


def load_arrays(path: Path) -> dict[str, dict[str, np.ndarray]]:
    """What :func:`save_arrays` wrote."""
    out: dict[str, dict[str, np.ndarray]] = {}
    with open_npz(path) as npz:
        for key in npz.files:
            group, _, name = key.rpartition("/")
            out.setdefault(group, {})[name] = npz[key]
    return out


def save_pickle(path: Path, result: Any) -> None:
    """Any picklable result (a task of ``teamslam paper``: plain numbers, a dataset)."""
    with path.open("wb") as f:
        pickle.dump(result, f, protocol=pickle.HIGHEST_PROTOCOL)


def load_pickle(path: Path) -> Any:
    """What :func:`save_pickle` wrote (a file this study's own output folder holds)."""
    with path.open("rb") as f:
        return pickle.load(f)


def _first_difference(stored: Any, ours: Any, where: str = "") -> str | None:
    """The first setting (dotted path) where two JSON values differ, with both values."""
    if isinstance(stored, dict) and isinstance(ours, dict):
        for key in sorted(stored.keys() | ours.keys()):
            if key not in stored or key not in ours:
                return f"{where}{key} only in {'the stored runs' if key in stored else 'ours'}"
            found = _first_difference(stored[key], ours[key], f"{where}{key}.")
            if found:
                return found
        return None
    if stored != ours:
        return f"{where.rstrip('.')} is {json.dumps(stored)} there, {json.dumps(ours)} here"
    return None


class RunStore:
    """One file per finished run of a study, in ``directory``.

    Parameters
    ----------
    directory
        The folder of the runs (created with the first run).
    study
        What every run depends on (JSON-able): the settings, not the number of runs, so that a
        resumed study may also ask for more runs than the stored ones.
    resume
        Read the stored runs (refusing those of another study); otherwise they are replaced.
    suffix, save, load
        The runs' file suffix, and how one is written to and read from a path.

    Raises
    ------
    InputError
        ``resume`` and the folder holds runs of another study, or an unreadable ``study.json``.

    Attributes
    ----------
    loaded, saved
        How many runs were read back, and written.
    """

    def __init__(
        self,
        directory: str | Path,
        study: dict,
        resume: bool = False,
        suffix: str = ".npz",
        save: Callable[[Path, Any], None] = save_arrays,
        load: Callable[[Path], Any] = load_arrays,
    ):
        self.directory = Path(directory)
        self.study = json.loads(json.dumps(json_safe(study), sort_keys=True))
        self.resume = resume
        self.suffix = suffix
        self._save, self._load = save, load
        self.loaded = self.saved = 0
        self._started = False
        self._stored: set[str] = set()
        if resume:
            self._check()
            self._stored = {p.name for p in self._files()}

    def _files(self) -> list[Path]:
        if not self.directory.is_dir():
            return []
        pattern = re.compile(r"run_[0-9a-f]+" + re.escape(self.suffix))  # not a partial file
        return sorted(p for p in self.directory.iterdir() if pattern.fullmatch(p.name))

    def _check(self) -> None:
        path = self.directory / STUDY_FILE
        if not path.is_file():
            if self._files():
                raise InputError(f"{self.directory} holds runs but no {STUDY_FILE}: cannot resume")
            return
        try:
            stored = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: not a study file ({exc})") from None
        differs = _first_difference(stored, self.study)
        if differs:
            raise InputError(
                f"{self.directory} holds runs of another study ({differs}): resume with the "
                "same settings, or choose another --out"
            )

    def name(self, key: Hashable) -> str:
        """The file name of run ``key`` (an integer: its number; anything else: its digest)."""
        if isinstance(key, int):
            return f"run_{key:06d}{self.suffix}"
        import hashlib

        return f"run_{hashlib.sha256(repr(key).encode()).hexdigest()[:20]}{self.suffix}"

    def __contains__(self, key: Hashable) -> bool:
        return self.name(key) in self._stored

    def load(self, key: Hashable) -> Any:
        """The stored run ``key``.

        Raises
        ------
        InputError
            Its file cannot be read (named).
        """
        path = self.directory / self.name(key)
        try:
            result = self._load(path)
        except (OSError, ValueError, EOFError, pickle.UnpicklingError) as exc:
            raise InputError(f"{path}: not a readable stored run ({exc})") from None
        self.loaded += 1
        return result

    def save(self, key: Hashable, result: Any) -> None:
        """Keep run ``key`` (atomically). The first run of a study not resumed removes the runs
        stored before it; the first of any writes ``study.json``.

        Raises
        ------
        OutputError
            The file cannot be written (named).
        """
        if not self._started:
            with writing(self.directory):
                self.directory.mkdir(parents=True, exist_ok=True)
                if not self.resume:
                    for old in self._files():
                        old.unlink()
            write_json(self.directory / STUDY_FILE, self.study)
            self._started = True
        name = self.name(key)
        write_atomic(self.directory / name, lambda tmp: self._save(tmp, result))
        self._stored.add(name)
        self.saved += 1
