"""Run one command in a sandbox: the launcher that ``classroom grade`` puts in front of each submission's kernel.

A student's notebook runs arbitrary code, so its kernel is given as little as it needs to run a chapter. This
launcher caps the memory (on Linux ``RLIMIT_DATA``, the private writable mappings: a ``bytearray(30 << 30)``
raises ``MemoryError`` in that cell instead of taking the machine's memory; not the address space, which PyPI's
CUDA build of torch fills with its libraries on import, far past any useful cap) and the CPU time
(``RLIMIT_CPU``: the kernel is killed when it has used that many CPU seconds), soft and hard, so the kernel cannot
raise them again; then it hands
the command to bubblewrap (``bwrap``, a maintained tool made for this, Debian's ``bubblewrap``), which runs it

* in new PID, IPC, UTS, network and mount namespaces (and a new user namespace when the grader is not root):
  its own ``/proc``, in which it sees only its own processes; when ``bwrap`` (the namespace's first process)
  ends, every process the kernel started ends with it;
* as an unprivileged uid: ``nobody`` outside the sandbox when the grader is root (bwrap sets the namespaces up
  as root, then ``setpriv`` drops every capability and the uid before the command starts), and the grader's own
  uid, mapped to ``nobody`` in a user namespace, when it is not (an unprivileged user has no other uid to give);
* on a root file system made of nothing but: the system's programs and libraries (``/usr`` and its links) and
  the Python environment, read-only; a minimal ``/dev`` (null, zero, random, a private pts and shm); no
  ``/sys`` and no cgroup file system; a few files of ``/etc`` that libraries read; the folders it is given
  (read-only or writable, at the same paths); a private home, and a private ``/tmp`` of
  :data:`TMP_BYTES`.

:func:`available` tells whether bwrap works on this machine (Linux with bubblewrap installed, and user namespaces
allowed when the grader is not root); where it does not, ``classroom grade`` refuses to run submissions unless the
teacher passes ``--no-sandbox``, in which case this launcher applies the limits alone.

The launcher is run as a script (``python -I sandbox.py ...``), never imported as ``vdtutorial.course.sandbox`` in
the launched process: it uses only the standard library, and nothing of the package needs to load before the
sandbox is made.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/classroom.py, notebooks/TEACHING.md).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

#: This file, run by path as the launcher.
LAUNCHER = Path(__file__).resolve()
#: The uid and gid the sandboxed command runs as (``nobody``).
NOBODY = 65534
#: The system's programs and libraries, read-only in the sandbox (those that exist: links stay links).
SYSTEM = ("/usr", "/bin", "/sbin", "/lib", "/lib32", "/lib64", "/libx32")
#: Files and folders of ``/etc`` that the dynamic linker, fonts, time zones, TLS and user look-ups read.
ETC = (
    "/etc/ld.so.cache",
    "/etc/ld.so.conf",
    "/etc/ld.so.conf.d",
    "/etc/alternatives",
    "/etc/fonts",
    "/etc/localtime",
    "/etc/ssl",
    "/etc/mime.types",
    "/etc/nsswitch.conf",
    "/etc/passwd",
    "/etc/group",
)
#: The environment variables the command keeps (any other, a token or a password among them, is not passed on).
#: The last three pin the CPU's vector kernels (``vdtutorial.runner.kernels.PINNED``): a check compares the kernel's
#: numbers with the grader's own, so both must round the same way.
KEPT_ENV = (
    "PATH",
    "LANG",
    "LANGUAGE",
    "TZ",
    "TERM",
    "PYTHONPATH",
    "MPLBACKEND",
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "ATEN_CPU_CAPABILITY",
    "ONEDNN_MAX_CPU_ISA",
    "OPENBLAS_CORETYPE",
)
KEPT_ENV_PREFIXES = ("LC_", "VDTUTORIAL_", "JUPYTER_")
#: The size of the sandbox's ``/tmp`` (a file system in memory, which the memory cap does not count).
TMP_BYTES = 256 << 20
#: What ``classroom grade`` says where no sandbox can be made.
SAFE_ROUTES = (
    "grade on Linux with bubblewrap installed (apt-get install bubblewrap) and user namespaces allowed, "
    "or in a Linux container or VM that has them"
)


def command(
    cmd: list[str],
    memory_bytes: int,
    cpu_seconds: int,
    home_under: Path,
    read_only: list = (),
    writable: list[Path] = (),
    given: list[str] = (),
    sandboxed: bool = True,
) -> list[str]:
    """``cmd`` prefixed with the launcher, which applies the limits and then replaces itself with ``cmd`` in the
    sandbox (with ``sandboxed=False``, the limits alone). ``cmd`` runs in a new empty folder made under
    ``home_under``, its ``HOME``. ``read_only``: paths, or ``(source, destination)`` pairs, to
    show it read-only; ``writable``: folders it may write (same paths inside); ``given``: files handed to ``cmd``,
    which names them by path: each is copied into its home, readable by the sandbox's uid alone, and ``cmd``
    names the copy instead (a kernel's connection file, which Jupyter writes readable by its owner alone, wherever
    it likes; Jupyter's ``{connection_file}`` may stand for it)."""
    head = [
        sys.executable,
        "-I",
        str(LAUNCHER),
        "--memory",
        str(memory_bytes),
        "--cpu",
        str(cpu_seconds),
        "--home-under",
        str(home_under),
    ]
    for item in read_only:
        source, dest = (item, item) if isinstance(item, (str, Path)) else item
        head += ["--ro", str(source), str(dest)]
    head += [arg for folder in writable for arg in ("--rw", str(folder))]
    head += [arg for path in given for arg in ("--give", str(path))]
    if not sandboxed:
        head.append("--no-sandbox")
    return head + ["--"] + list(cmd)


def python_paths() -> list[Path]:
    """The folders this Python needs, to show read-only to a kernel started with it: its prefixes (a venv's
    and the interpreter's it was made from) and every other folder on ``sys.path`` (e.g. ``PYTHONPATH``). A
    folder that holds the course package's own source checkout is left out: the caller shows the package alone."""
    checkout = LAUNCHER.parents[2]
    found = []
    for entry in [sys.prefix, sys.base_prefix, sys.exec_prefix, *sys.path]:
        path = Path(entry).resolve() if entry else None
        if path is None or not path.is_dir() or path == checkout or checkout.is_relative_to(path):
            continue
        if not any(path.is_relative_to(other) for other in found):
            found = [other for other in found if not other.is_relative_to(path)] + [path]
    return found


def memory_limit() -> int:
    """The ``resource`` limit that ``--memory`` sets: ``RLIMIT_DATA`` on Linux, where since kernel 4.7 it
    counts every private writable mapping (heap, ``mmap``-ed arrays, thread stacks) but not the code and
    read-only data of shared libraries; ``RLIMIT_AS`` elsewhere (macOS counts data differently)."""
    import resource

    return resource.RLIMIT_DATA if sys.platform.startswith("linux") else resource.RLIMIT_AS


def available() -> str | None:
    """``None`` when this machine can run a command in the sandbox, else why not (one line): tried once in a
    child process with a trivial command."""
    if not sys.platform.startswith("linux"):
        return f"{sys.platform} has no bubblewrap sandbox"
    missing = [tool for tool in ("bwrap", "setpriv") if shutil.which(tool) is None]
    if missing:
        return f"{' and '.join(missing)} not found"
    with tempfile.TemporaryDirectory(prefix="vdtutorial_sandbox_probe_") as scratch:
        os.chmod(scratch, 0o755)
        probe = command(["/bin/sh", "-c", "exit 0"], 1 << 30, 60, home_under=Path(scratch))
        run = subprocess.run(probe, capture_output=True, text=True, check=False)
    if run.returncode != 0:
        return "bubblewrap cannot make a sandbox here: " + (run.stderr.strip().splitlines() or ["?"])[-1]
    return None


def _bwrap(cmd: list[str], home: Path, read_only: list[tuple[str, str]], writable: list[str]) -> list[str]:
    """The bubblewrap command line that runs ``cmd`` as described in the module's docstring."""
    root = os.getuid() == 0
    argv = [
        "bwrap",
        "--die-with-parent",
        "--new-session",
        "--unshare-pid",
        "--unshare-net",
        "--unshare-ipc",
        "--unshare-uts",
        "--unshare-cgroup-try",
        "--hostname",
        "sandbox",
    ]
    if root:  # namespaces made as root, then the uid dropped inside: never root, not even in a user namespace
        argv += ["--cap-add", "CAP_SETUID", "--cap-add", "CAP_SETGID"]
        cmd = [
            "setpriv",
            f"--reuid={NOBODY}",
            f"--regid={NOBODY}",
            "--clear-groups",
            "--inh-caps=-all",
            "--bounding-set=-all",
            "--no-new-privs",
            "--",
        ] + cmd
    else:
        argv += ["--unshare-user", "--uid", str(NOBODY), "--gid", str(NOBODY)]
    argv += ["--proc", "/proc", "--dev", "/dev"]
    for path in SYSTEM:
        if os.path.islink(path):
            argv += ["--symlink", os.readlink(path), path]
        elif os.path.isdir(path):
            argv += ["--ro-bind", path, path]
    mounts = [("--ro-bind", path, path) for path in ETC if os.path.exists(path)]
    mounts += [("--ro-bind", source, dest) for source, dest in read_only]
    mounts += [("--bind", folder, folder) for folder in writable + [str(home)]]
    argv += ["--perms", "1777", "--size", str(TMP_BYTES), "--tmpfs", "/tmp"]
    made = {"/", "/proc", "/dev", "/tmp", *SYSTEM}
    for _, _, dest in mounts:  # the folders above a mount point: created readable by all (bwrap makes them 0700)
        for parent in reversed(Path(dest).parents):
            if str(parent) not in made:
                made.add(str(parent))
                argv += ["--perms", "0755", "--dir", str(parent)]
    for flag, source, dest in mounts:
        argv += [flag, source, dest]
    argv += ["--clearenv", "--setenv", "HOME", str(home), "--setenv", "TMPDIR", "/tmp", "--setenv", "USER", "nobody"]
    for name, value in os.environ.items():
        if name in KEPT_ENV or name.startswith(KEPT_ENV_PREFIXES):
            argv += ["--setenv", name, value]
    if "JPY_PARENT_PID" in os.environ:  # a kernel's parent, which it watches: in its PID namespace, bwrap (pid 1)
        argv += ["--setenv", "JPY_PARENT_PID", "1"]
    return argv + ["--chdir", str(home), "--"] + cmd


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="run a command with a memory and a CPU-time cap in a sandbox")
    parser.add_argument("--memory", type=int, required=True, help="memory cap in bytes (see memory_limit)")
    parser.add_argument("--cpu", type=int, required=True, help="CPU-time cap in seconds")
    parser.add_argument("--home-under", required=True, help="run in a new folder made here, which is also HOME")
    parser.add_argument(
        "--ro", nargs=2, action="append", default=[], metavar=("SOURCE", "DEST"), help="show SOURCE read-only at DEST"
    )
    parser.add_argument("--rw", action="append", default=[], help="a folder the command may write")
    parser.add_argument(
        "--give",
        action="append",
        default=[],
        help="a file handed to the command: copied into its home, and named by the copy's path",
    )
    parser.add_argument("--no-sandbox", action="store_true", help="the limits alone")
    parser.add_argument("cmd", nargs=argparse.REMAINDER, help="-- then the command")
    args = parser.parse_args(argv)
    cmd = args.cmd[1:] if args.cmd[:1] == ["--"] else args.cmd
    import resource

    home = Path(tempfile.mkdtemp(prefix="home_", dir=args.home_under))
    for k, path in enumerate(args.give):
        copy = home / f"given_{k}_{Path(path).name}"
        shutil.copyfile(path, copy)
        os.chmod(copy, 0o600)
        cmd = [str(copy) if arg == path else arg for arg in cmd]
        if os.getuid() == 0 and not args.no_sandbox:
            os.chown(copy, NOBODY, NOBODY)
    if os.getuid() == 0 and not args.no_sandbox:
        for path in [home, *args.rw]:
            os.chown(path, NOBODY, NOBODY)
    resource.setrlimit(memory_limit(), (args.memory, args.memory))
    resource.setrlimit(resource.RLIMIT_CPU, (args.cpu, args.cpu))
    if args.no_sandbox:
        (home / "tmp").mkdir()
        os.environ.update(HOME=str(home), TMPDIR=str(home / "tmp"))
        os.chdir(home)
        os.execvp(cmd[0], cmd)
    full = _bwrap(cmd, home, [tuple(pair) for pair in args.ro], args.rw)
    os.execvp(full[0], full)


if __name__ == "__main__":
    main()
