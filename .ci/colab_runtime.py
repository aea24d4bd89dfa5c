"""Google Colab's published runtime (a pip freeze), for CI's Colab leg.

python .ci/colab_runtime.py FREEZE > colab-constraints.txt
    the freeze as pip constraints, one ``name==version`` a package. A line ``name @ URL`` of a wheel (Colab's
    torch from PyTorch's CPU index) becomes ``name==VERSION`` read from the wheel's file name, without its
    local tag (PyPI's torch 2.11.0 stands in for Colab's 2.11.0+cpu); other direct references (a git
    checkout, a local sdist) are left out: they are not on an index. So are NVIDIA's CUDA libraries
    (``nvidia-*``): Colab's CPU torch does not use them, and Colab's own versions of them (for other
    packages) clash with the exact ones PyPI's CUDA build of torch 2.11.0 requires.
python .ci/colab_runtime.py FREEZE --check NAME [NAME ...]
    exit 1, naming them, if the installed versions of these packages are not the freeze's.
"""

import importlib.metadata as md
import re
import sys
from pathlib import Path
from urllib.parse import unquote


def canonical(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def constraints(freeze: Path) -> dict[str, str]:
    pins = {}
    for line in freeze.read_text().splitlines():
        if not line.strip() or line.startswith("#") or line.lower().startswith("nvidia-"):
            continue
        if " @ " not in line:
            name, version = line.strip().split("==")
            pins[canonical(name)] = version
            continue
        name, url = (part.strip() for part in line.split(" @ ", 1))
        if wheel := re.search(r"/([^/]+)-([^-/]+)-[^/-]+-[^/-]+-[^/-]+\.whl", unquote(url)):
            pins[canonical(name)] = wheel[2].split("+")[0]
    return pins


if __name__ == "__main__":
    pins = constraints(Path(sys.argv[1]))
    if sys.argv[2:3] != ["--check"]:
        print("\n".join(f"{name}=={version}" for name, version in pins.items()))
        sys.exit(0)
    changed = [
        f"{name} {md.version(name)} (Colab's: {pins[canonical(name)]})"
        for name in sys.argv[3:]
        if md.version(name).split("+")[0] != pins[canonical(name)]
    ]
    print(
        "not Colab's: " + "; ".join(changed)
        if changed
        else "Colab's versions, unchanged: " + ", ".join(f"{name} {pins[canonical(name)]}" for name in sys.argv[3:])
    )
    sys.exit(1 if changed else 0)
