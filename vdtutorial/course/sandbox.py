"""Run one command with limits: the launcher that ``classroom grade`` puts in front of each submission's kernel.

A student's notebook runs arbitrary code. Before the kernel starts, this launcher

* caps the memory (on Linux ``RLIMIT_DATA``, the private writable mappings: a ``bytearray(30 << 30)``
  raises ``MemoryError`` in that cell instead of taking the machine's memory; not the address space, which
  PyPI's CUDA build of torch fills past 4 GB with its libraries on import, GPU or not) and the CPU time
  (``RLIMIT_CPU``: the kernel is killed when it has used that many CPU seconds), soft and hard, so the
  kernel cannot raise them again;
* on Linux, where unprivileged user namespaces are allowed, moves the process into new user, mount and
  network namespaces: no network interface but a loopback that is down, and every file system mounted
  read-only except the folders it is told are writable (the notebook's folder, a throwaway home) and a
  private ``/dev/shm``. Inside, the kernel is ``nobody`` (the grader's uid outside), so it keeps no
  capability after ``exec`` and cannot undo the mounts.

Where namespaces are not allowed (macOS, Windows, containers that forbid them) only the limits apply;
:func:`isolation_available` tells the caller so, and ``classroom grade`` says it plainly.

The launcher is run as a script (``python -I sandbox.py ...``), never imported as ``vdtutorial.course.sandbox`` in
the launched process: importing the package loads numpy, whose threads would forbid ``unshare(CLONE_NEWUSER)``
(a process must be single-threaded to enter a new user namespace). It uses only the standard library.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/classroom.py, notebooks/TEACHING.md).
"""
from __future__ import annotations

import argparse
import ctypes
import os
import subprocess
import sys
import tempfile
from pathlib import Path

#: This file, run by path as the launcher.
LAUNCHER = Path(__file__).resolve()

_CLONE_NEWNS, _CLONE_NEWUSER, _CLONE_NEWNET = 0x00020000, 0x10000000, 0x40000000
_MS_RDONLY, _MS_REMOUNT, _MS_BIND, _MS_REC, _MS_PRIVATE = 1, 32, 4096, 16384, 1 << 18
#: The id the kernel has inside its user namespace (the grader's own uid and gid outside it).
_NOBODY = 65534
#: Mount flags a remount inside a user namespace must keep (the kernel refuses to clear them): these
#: ``statvfs`` flags have the same values as the ``MS_*`` mount flags.
_KEPT_FLAGS = (os.ST_NOSUID | os.ST_NODEV | os.ST_NOEXEC | os.ST_NOATIME | os.ST_NODIRATIME
               | os.ST_RELATIME) if hasattr(os, "ST_NOSUID") else 0
#: Kernel file systems that hold no user files: left as they are (``/proc``, ``/sys``, ``/dev``...).
_PSEUDO_FS = {"proc", "sysfs", "cgroup", "cgroup2", "devpts", "devtmpfs", "mqueue", "debugfs", "tracefs",
              "securityfs", "pstore", "bpf", "configfs", "fusectl", "hugetlbfs", "binfmt_misc", "autofs",
              "efivarfs", "nsfs", "rpc_pipefs"}


def command(cmd: list[str], memory_bytes: int, cpu_seconds: int, home_under: Path | None = None,
            writable: list[Path] = (), isolate: bool = False) -> list[str]:
    """``cmd`` prefixed with the launcher, which applies the limits (and, with ``isolate``, the namespaces
    with the folders ``writable``) and then replaces itself with ``cmd``. With ``home_under``, ``cmd`` runs in
    a new empty folder there, which is also its ``HOME`` and holds its ``TMPDIR`` (and is writable)."""
    head = [sys.executable, "-I", str(LAUNCHER), "--memory", str(memory_bytes), "--cpu", str(cpu_seconds)]
    if home_under is not None:
        head += ["--home-under", str(home_under)]
    if isolate:
        head += ["--isolate"] + [arg for folder in writable for arg in ("--writable", str(folder))]
    return head + ["--"] + list(cmd)


def memory_limit() -> int:
    """The ``resource`` limit that ``--memory`` sets: ``RLIMIT_DATA`` on Linux, where since kernel 4.7 it
    counts every private writable mapping (heap, ``mmap``-ed arrays, thread stacks) but not the code and
    read-only data of shared libraries; ``RLIMIT_AS`` elsewhere (macOS counts data differently)."""
    import resource

    return resource.RLIMIT_DATA if sys.platform.startswith("linux") else resource.RLIMIT_AS


def isolation_available() -> bool:
    """Whether this machine lets an unprivileged process enter its own user, mount and network namespaces
    (tried once in a child process: Linux only, and some containers and distributions forbid it)."""
    if not sys.platform.startswith("linux"):
        return False
    probe = command(["/bin/sh", "-c", "exit 0"], 1 << 30, 60, isolate=True)
    return subprocess.run(probe, capture_output=True).returncode == 0


def _libc():
    libc = ctypes.CDLL(None, use_errno=True)
    libc.mount.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_ulong, ctypes.c_void_p]
    return libc


def _check(result: int, what: str) -> None:
    if result != 0:
        errno = ctypes.get_errno()
        raise OSError(errno, f"{what}: {os.strerror(errno)}")


def _mounts() -> list[tuple[str, str, bool]]:
    """(mount point, file system type, read-only) of every mount this process sees."""
    found = []
    for line in Path("/proc/self/mountinfo").read_text().splitlines():
        fields = line.split()
        tail = fields[fields.index("-") + 1:]
        point = fields[4].encode().decode("unicode_escape")   # spaces etc. are written as octal escapes
        found.append((point, tail[0], "ro" in fields[5].split(",")))
    return found


def _enter_namespaces() -> None:
    """New user, mount and network namespaces, in which the process is ``nobody`` (never root, even when
    the grader is: the capabilities that made the mounts are dropped at ``exec``)."""
    uid, gid = os.getuid(), os.getgid()
    _check(_libc().unshare(_CLONE_NEWUSER | _CLONE_NEWNS | _CLONE_NEWNET), "unshare")
    Path("/proc/self/setgroups").write_text("deny")
    Path("/proc/self/uid_map").write_text(f"{_NOBODY} {uid} 1")
    Path("/proc/self/gid_map").write_text(f"{_NOBODY} {gid} 1")


def _read_only_except(writable: list[Path]) -> None:
    """Every file system read-only but the folders ``writable`` (bound onto themselves first, so they stay
    separate writable mounts) and a fresh private ``/dev/shm``."""
    libc = _libc()
    _check(libc.mount(None, b"/", None, _MS_REC | _MS_PRIVATE, None), "make mounts private")
    keep = {str(Path(folder).resolve()) for folder in writable}
    for folder in sorted(keep):
        _check(libc.mount(folder.encode(), folder.encode(), None, _MS_BIND | _MS_REC, None), f"bind {folder}")
    for point, fstype, read_only in _mounts():
        if read_only or fstype in _PSEUDO_FS or point in keep or point == "/dev/shm":
            continue
        flags = _MS_REMOUNT | _MS_BIND | _MS_RDONLY | (os.statvfs(point).f_flag & _KEPT_FLAGS)
        _check(libc.mount(None, point.encode(), None, flags, None), f"remount {point} read-only")
    if Path("/dev/shm").is_dir():
        _check(libc.mount(b"tmpfs", b"/dev/shm", b"tmpfs", 0, None), "private /dev/shm")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="run a command with a memory and a CPU-time cap, "
                                                 "optionally without network and with a read-only file system")
    parser.add_argument("--memory", type=int, required=True, help="memory cap in bytes (see memory_limit)")
    parser.add_argument("--cpu", type=int, required=True, help="CPU-time cap in seconds")
    parser.add_argument("--isolate", action="store_true", help="new user, mount and network namespaces")
    parser.add_argument("--writable", action="append", default=[], help="a folder that stays writable")
    parser.add_argument("--home-under", default=None, help="run in a new folder made here, which is also HOME")
    parser.add_argument("cmd", nargs=argparse.REMAINDER, help="-- then the command")
    args = parser.parse_args(argv)
    cmd = args.cmd[1:] if args.cmd[:1] == ["--"] else args.cmd
    import resource

    writable = [Path(folder) for folder in args.writable]
    if args.home_under:
        home = Path(tempfile.mkdtemp(prefix="home_", dir=args.home_under))
        (home / "tmp").mkdir()
        os.environ.update(HOME=str(home), TMPDIR=str(home / "tmp"))
        os.chdir(home)
        writable.append(home)
    if args.isolate:
        _enter_namespaces()
        _read_only_except(writable)
    resource.setrlimit(memory_limit(), (args.memory, args.memory))
    resource.setrlimit(resource.RLIMIT_CPU, (args.cpu, args.cpu))
    os.execvp(cmd[0], cmd)


if __name__ == "__main__":
    main()
