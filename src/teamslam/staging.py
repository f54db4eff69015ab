"""Directories written whole or not at all: built in a staging folder, then moved into place.

The staging folder is a hidden sibling of the target (``.NAME.XXXXXXXX``, the same filesystem,
so the move is one rename). Until :meth:`StagedDirectory.commit` the target holds what it held
before; an exception or Ctrl-C inside ``with StagedDirectory(target)`` removes the staging folder
and leaves the target untouched. A directory already at the target is replaced whole: it is
renamed aside, the staging folder renamed into its place, and the old one removed — no file of it
survives, and if the second rename fails the old directory is put back.

Which directory may be replaced is the caller's rule (a dataset writer replaces a dataset, a run
writer an earlier run only when asked); this module only stages and swaps.
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

__all__ = ["StagedDirectory"]


class StagedDirectory:
    """A staging folder beside ``target``, created at once (so creating one checks that the
    target's parent is writable, before any work is done).

    Parameters
    ----------
    target
        The directory to write; its parent is created if missing.

    Attributes
    ----------
    target
        Where the directory goes.
    path
        The staging folder to write into.

    Raises
    ------
    OSError
        The parent cannot be created or written (a read-only folder, a file in the way).
    """

    def __init__(self, target: str | Path) -> None:
        self.target = Path(target)
        self.target.parent.mkdir(parents=True, exist_ok=True)
        self.path = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.", dir=self.target.parent))
        self.done = False

    def commit(self) -> Path:
        """Move the staging folder into place (replacing what is there); the target."""
        if self.done:
            return self.target
        if self.target.exists() or self.target.is_symlink():
            old = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.old.", dir=self.target.parent))
            old.rmdir()
            self.target.replace(old)
            try:
                self.path.replace(self.target)
            except BaseException:
                old.replace(self.target)
                raise
            self.done = True
            if old.is_dir() and not old.is_symlink():
                shutil.rmtree(old, ignore_errors=True)
            else:
                old.unlink(missing_ok=True)
        else:
            self.path.replace(self.target)
            self.done = True
        return self.target

    def discard(self) -> None:
        """Remove the staging folder (nothing reaches the target)."""
        if not self.done:
            shutil.rmtree(self.path, ignore_errors=True)
            self.done = True

    def __enter__(self) -> StagedDirectory:
        return self

    def __exit__(self, kind, value, traceback) -> None:
        if kind is None:
            self.commit()
        else:
            self.discard()
