"""The single-writer lock of a chunk store: a file created with O_CREAT|O_EXCL holding pid and host.

One writer per store: a second sweep on the same store is refused while the first runs, and a lock
left by a process that died on this host (kill -9) is taken over. Kept apart from the store's
format (:mod:`stabjax.run.store`), which only names the file.
"""
from __future__ import annotations

import contextlib
import json
import os
import socket
import time
from pathlib import Path

from ..errors import StabjaxError


class StoreError(StabjaxError):
    """The store cannot be used for this run (another writer, a different computation): exit 2."""


class StoreIOError(StabjaxError):
    """Writing the store failed (full disk, no permission): exit 1. Finished chunks are kept."""

    exit_code = 1


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _dead(holder: dict | None) -> bool:
    """Whether a lock's holder (its file's contents) is a process of this host that is gone: its lock is stale.
    Any other holder -- alive, of another host (we cannot tell), or not yet written -- may still run."""
    return bool(holder) and holder.get("host") == socket.gethostname() and isinstance(holder.get("pid"), int) \
        and not _pid_alive(holder["pid"])


def held(path: Path) -> bool:
    """Whether the lock file ``path`` is held by a writer that may still run: present, and not stale."""
    holder = Lock(path)._read()
    return holder is not None and not _dead(holder)


class Lock:
    """Exclusive writer lock: a file created with O_CREAT|O_EXCL holding pid and host.

    A lock left by a dead process on this host (kill -9) is stale and taken over; one held by a
    live process, or by any process on another host (we cannot tell), refuses the second writer.
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        self.held = False

    def _read(self) -> dict | None:
        try:
            return json.loads(self.path.read_text() or "{}")
        except FileNotFoundError:
            return None
        except (OSError, ValueError):
            return {}

    def acquire(self, store: Path):
        me = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        for _ in range(50):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self._read()
                if holder is None:
                    continue  # released meanwhile
                if not holder:  # being written this instant by its creator
                    time.sleep(0.05)
                    holder = self._read()
                    if holder is None:
                        continue
                if _dead(holder):
                    self._break(holder)
                    continue
                if not holder and self._age() > 10:  # its creator died between creating and writing it
                    self._break(holder)
                    continue
                who = f"pid {holder.get('pid')} on {holder.get('host')}" if holder else "another process"
                raise StoreError(
                    f"{store} is in use by {who} (lock {self.path}, since {holder.get('started', '?') if holder else '?'}); "
                    "wait for it to finish, or use another --out. If that process is gone (another host), "
                    "delete the lock file by hand") from None
            except OSError as exc:
                raise StoreIOError(f"cannot create the lock {self.path}: {exc}") from None
            with os.fdopen(fd, "w") as f:
                f.write(json.dumps(me))
            self.held = True
            return
        raise StoreError(f"could not take the lock {self.path} (contended)")

    def _age(self) -> float:
        try:
            return time.time() - self.path.stat().st_mtime
        except OSError:
            return 0.0

    def _break(self, stale: dict):
        # only one process may break a stale lock: otherwise a second breaker could delete the
        # fresh lock the first one has just created
        guard = self.path.with_name(self.path.name + ".break")
        try:
            fd = os.open(guard, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            with contextlib.suppress(OSError):
                if time.time() - guard.stat().st_mtime > 30:  # a breaker died mid-way
                    guard.unlink()
            time.sleep(0.05)
            return
        try:
            os.close(fd)
            if self._read() == stale:
                self.path.unlink(missing_ok=True)
        finally:
            guard.unlink(missing_ok=True)

    def release(self):
        if self.held:
            holder = self._read()
            if holder and holder.get("pid") == os.getpid():
                self.path.unlink(missing_ok=True)
            self.held = False
