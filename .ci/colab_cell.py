"""Print the README's Colab cell (the ```python block after the colab-cell marker) as an IPython script,
with its SOURCE and BOOK set to the given wheel and folder: CI runs it as Colab would run the cell.

Usage: python .ci/colab_cell.py README.md WHEEL BOOK > cell.ipy && ipython cell.ipy
"""
import re
import sys
from pathlib import Path

readme, wheel, book = sys.argv[1:4]
text = Path(readme).read_text()
cell = re.search(r"<!-- colab-cell.*?-->\n```python\n(.*?)```", text, re.S)[1]
first, *rest = cell.splitlines()
assert first.startswith("SOURCE, BOOK = "), first
print("\n".join([f"SOURCE, BOOK = {wheel!r}, {book!r}", *rest]))
