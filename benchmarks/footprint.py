"""Flash, RAM and stack of the shipped filters on a Cortex-M7 (arm-none-eabi-gcc -O2, hard float).

flash = text + data of the filter's objects (arm-none-eabi-size); state = the
caller's ``<prefix>_state`` struct (all of the filter's RAM: no globals, no
heap); stack = the deepest frame of the step (gcc -fstack-usage).
"""
from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks.common import emit, parser

ROOT = Path(__file__).resolve().parents[1]
CORTEX_M7 = ["-mcpu=cortex-m7", "-mthumb", "-mfpu=fpv5-d16", "-mfloat-abi=hard"]
FLAGS = ["-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-O2", "-fstack-usage"]

STATE_SIZE = r"""
#include "%s.h"
const unsigned long skigen_state_bytes = sizeof(%s_state);
"""


def measure(folder: Path, work: Path) -> dict:
    """Compile one generated filter folder for the Cortex-M7 and size it."""
    prefix = next(p.stem.removesuffix("_kernel") for p in folder.glob("*_kernel.h"))
    probe = work / f"{folder.name}_size.c"
    probe.write_text(STATE_SIZE % (prefix, prefix))
    objs = []
    for src in sorted(folder.glob("*.c")):
        obj = work / f"{folder.name}_{src.stem}.o"
        subprocess.run(["arm-none-eabi-gcc", *CORTEX_M7, *FLAGS, "-I", str(folder), "-c", str(src), "-o", str(obj)],
                       check=True, cwd=work)
        objs.append(obj)
    size = subprocess.run(["arm-none-eabi-size", *map(str, objs)], capture_output=True, text=True, check=True).stdout
    text = sum(int(line.split()[0]) + int(line.split()[1]) for line in size.splitlines()[1:])
    probe_obj = work / f"{folder.name}_size.o"
    subprocess.run(["arm-none-eabi-gcc", *CORTEX_M7, "-O2", "-I", str(folder), "-c", str(probe), "-o", str(probe_obj)],
                   check=True)
    state = _read_constant(probe_obj)
    stack = max((int(m.group(1)) for su in work.glob(f"{folder.name}_*.su")
                 for m in re.finditer(r"\t(\d+)\t", su.read_text())), default=0)
    return {"flash_bytes": text, "state_bytes": state, "max_stack_bytes": stack}


def _read_constant(obj: Path) -> int:
    """The value of ``skigen_state_bytes`` in an object file (little-endian 32-bit)."""
    dump = subprocess.run(["arm-none-eabi-objcopy", "-O", "binary", "-j", ".rodata", str(obj), "/dev/stdout"],
                          capture_output=True, check=True).stdout
    return int.from_bytes(dump[:4], "little")


def main(argv=None) -> int:
    args = parser("footprint", seeds=1).parse_args(argv)
    if not shutil.which("arm-none-eabi-gcc"):
        print("arm-none-eabi-gcc not installed: apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi",
              file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        report = {d.name: measure(d, Path(tmp)) for d in sorted((ROOT / "generated").iterdir()) if d.is_dir()}
    rows = ["Cortex-M7 (arm-none-eabi-gcc -O2, fpv5-d16 hard float)",
            f"{'filter':28s} {'flash B':>8s} {'state B':>8s} {'stack B':>8s}"]
    rows += [f"{k:28s} {v['flash_bytes']:8d} {v['state_bytes']:8d} {v['max_stack_bytes']:8d}" for k, v in report.items()]
    return emit(report, args.json, "\n".join(rows))


if __name__ == "__main__":
    sys.exit(main())
