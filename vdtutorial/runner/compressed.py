"""torch files written whole and gzip-compressed: the run states (:mod:`vdtutorial.runner.resume`) and the
pre-trained checkpoints (:mod:`vdtutorial.experiments.checkpoints`).

Why compress: ``torch.save`` stores every float32 in full, and a policy's weights (a pruned VD policy's zeros and
one-byte masks above all) shrink under gzip, the shipped checkpoints by 32% and an image run's state by 60%
(docs/results.md, "Compressed run states and checkpoints"); run states are committed as long grids go, and
checkpoints travel in every learner's copy.
Why write whole: a process killed at any moment (SIGKILL included) must leave the old file or the new one, never
half a file, so a write goes to a temporary file of its own, is flushed to the disk and is renamed over the path.

Reading takes either form: ``torch.save``'s own (a zip archive, "PK") or gzip's (:data:`GZIP_MAGIC`), so files
written before compression still load.

Not taught in a chapter: a storage detail beneath the run states of chapter 07 and the checkpoints of chapter 05,
which read and write through it.
"""

from __future__ import annotations

import gzip
import io
import os
import tempfile
from pathlib import Path

import torch

#: The first two bytes of every gzip stream; ``torch.save``'s own format is a zip archive ("PK").
GZIP_MAGIC = b"\x1f\x8b"


def save_compressed(obj, path: str | os.PathLike) -> Path:
    """Write ``obj`` with ``torch.save``, gzip-compressed, to ``path`` so that a reader sees the old file or the new
    one, never a part: into a temporary file of its own (two processes writing the same path never share one),
    flushed to the disk, then renamed over ``path``. Equal objects give equal files (no time stamp inside)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as file:
            file.write(gzip.compress(buffer.getvalue(), compresslevel=6, mtime=0))
            file.flush()
            os.fsync(file.fileno())
        os.chmod(tmp, 0o644)  # mkstemp's 0o600 would hide the file from the other users of a shared folder
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def load_compressed(path: str | os.PathLike):
    """What :func:`save_compressed` wrote, or a plain ``torch.save`` file, on the CPU and with
    ``weights_only=True`` (plain tensors and containers only: a file from elsewhere cannot run code)."""
    data = Path(path).read_bytes()
    if data[:2] == GZIP_MAGIC:
        data = gzip.decompress(data)
    return torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
