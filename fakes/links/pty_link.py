"""The pseudo-terminal side of ``armbench emulate --pty``: whether this Python can make a pty at
all (:func:`require_pty`), and the ``--link PATH`` symlink to the pty's device, made and removed
without destroying anything that is not an emulator's (:func:`claim_link`,
:func:`release_link`)."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from armbench.drivers.model.errors import ArmbenchError

__all__ = ["PTY_DEVICE_DIR", "LinkError", "PtyUnavailable", "claim_link", "release_link",
           "require_pty"]


class PtyUnavailable(ArmbenchError):
    """This Python cannot make a pseudo-terminal (Windows: no ``termios``, no ``os.openpty``)."""


def require_pty() -> None:
    """Raise :class:`PtyUnavailable`, one line, unless a pty can be made here: the modules
    ``termios`` and ``tty`` import and ``os.openpty`` exists (all POSIX-only)."""
    try:
        import termios  # noqa: F401
        import tty  # noqa: F401
    except ImportError:
        missing = "termios"
    else:
        missing = "" if hasattr(os, "openpty") else "os.openpty"
    if missing:
        raise PtyUnavailable(f"--pty needs a POSIX pseudo-terminal; use --tcp HOST:PORT (this "
                             f"Python has no {missing})")


#: Where the kernel puts pseudo-terminal slaves: a symlink into it is one an emulator made.
PTY_DEVICE_DIR = "/dev/pts/"


class LinkError(ArmbenchError):
    """``--link PATH`` cannot be made without destroying something that is not ours."""


def _is_own_link(path: Path) -> bool:
    """A symlink to a pty slave (live or gone) is the kind an earlier emulator left there."""
    return path.is_symlink() and os.readlink(path).startswith(PTY_DEVICE_DIR)


def claim_link(link: Path, device: str) -> None:
    """Make ``link`` a symlink to ``device``, replacing only an emulator's earlier pty link.

    Anything else at ``link`` (a file, a device node such as the real arm's ``/dev/ttyUSB0``, a
    directory, another symlink) is refused with :class:`LinkError` and left as it is; the swap is
    atomic, so no moment exists where ``link`` points nowhere or at something half-made.
    """
    if not link.parent.is_dir():
        raise LinkError(f"--link {link}: folder {link.parent} does not exist")
    if os.path.lexists(link) and not _is_own_link(link):
        raise LinkError(f"--link {link}: something is already there (not an emulator's pty "
                        f"link); refusing to replace it")
    staging = link.with_name(f".{link.name}.{os.getpid()}.armbench-link")
    try:
        os.symlink(device, staging)
        if os.path.lexists(link) and not _is_own_link(link):  # appeared meanwhile
            raise LinkError(f"--link {link}: something appeared there; refusing to replace it")
        os.replace(staging, link)
    except OSError as exc:
        raise LinkError(f"--link {link}: cannot make the link ({exc.strerror or exc})") from exc
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(staging)


def release_link(link: Path, device: str) -> None:
    """Remove ``link`` if it is still the symlink to ``device`` this server made, else leave it."""
    with contextlib.suppress(OSError):
        if link.is_symlink() and os.readlink(link) == device:
            link.unlink()


