"""Result-CSV rows as text, and the helper process that formats and writes them.

Kept free of numpy and of the package's other modules: `ResultWriter` runs this file as a
script (`python -I -S csv_format.py PATH COLUMNS`) in a helper process that takes blocks of
rows as raw float64 bytes on its stdin and appends them to the CSV, so that a long run's
float formatting (Python's shortest round-trip `repr`, some 60 % of a co-simulated sample
without an estimator) runs beside the co-simulation instead of in it.

Protocol on stdin: per block an 8-byte little-endian byte count, then that many bytes of
native float64, row after row. End of input: the process writes nothing more and exits 0.
A block cut short (the parent died while sending it) is dropped whole, so the CSV always
ends with a whole row.
"""

from __future__ import annotations

import struct
import sys
from array import array

HEADER = struct.Struct("<Q")


def format_rows(rows: list[list[float]]) -> str:
    """CSV lines (each ended by a newline) of rows of Python floats: `repr` of each value,
    NaN as an empty cell.

    Character for character what `",".join("" if x != x else repr(x) for x in row)` gives
    per row: one `repr` of the list of lists (the formatting loop in C), its separators
    rewritten. "nan" occurs in no other float's repr, "], [" and ", " in none at all."""
    if not rows:
        return ""
    return repr(rows)[2:-2].replace("], [", "\n").replace(", ", ",").replace("nan", "") + "\n"


def _serve(path: str, columns: int) -> int:
    read = sys.stdin.buffer.read
    with open(path, "a", newline="") as f:
        while True:
            head = read(HEADER.size)
            if len(head) < HEADER.size:
                return 0
            (size,) = HEADER.unpack(head)
            data = read(size)
            if len(data) < size:
                return 0
            values = array("d")
            values.frombytes(data)
            flat = values.tolist()
            f.write(format_rows([flat[i:i + columns] for i in range(0, len(flat), columns)]))
            f.flush()


if __name__ == "__main__":
    import signal

    # the parent decides when to stop (it closes our stdin); a Ctrl-C reaching the process
    # group must not cut the rows it has already handed over
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    sys.exit(_serve(sys.argv[1], int(sys.argv[2])))
