"""G-code pipeline speed: parse + plan + sample 100 000 short linear moves, and parse speed
against the `gcodeparser` package (PyPI) on the same file in the same run; and the same for
the 5000-move CAM raster of the peer corpus (tests/fixtures/gcode/peer/cam_surface_raster.ngc).

The program is CAM-like: a wavy closed contour of 0.03-0.1 mm segments, one `G1 X.. Y..` block
each, in the nc: section of config/axis_default.yaml. numba compilation is timed separately
(first call) and excluded; each figure is the best of three runs. The machine is shared by
several engineers, so rates are given from this process's CPU time (what the code costs) and
from wall time (what it cost today, with the neighbours); single-threaded, the two agree on an
idle machine. Last printed line: one JSON object of the figures.

    .venv/bin/python benchmarks/gcode_speed.py
"""

from __future__ import annotations

import json
import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import gcodeparser

from feed_twin.gcode import load_nc_config, plan_program
from feed_twin.gcode.interpreter import Interpreter
from feed_twin.gcode.lexer import lex_line

T = TypeVar("T")

ROOT = Path(__file__).resolve().parent.parent
N_MOVES = 100_000
# The CAM program of the peer corpus: a 3D surface finishing raster of 5100 moves of 0.2 mm.
RASTER = ROOT / "tests" / "fixtures" / "gcode" / "peer" / "cam_surface_raster.ngc"
REPEATS = 3


def write_program(path: Path, n: int) -> None:
    lines = ["G21 G17 G90 G54 G64 G94", "G0 X50 Y0 Z5", "G1 Z0 F600", "F3000"]
    for k in range(1, n + 1):
        angle = 2.0 * math.pi * k / n * 20.0
        radius = 50.0 + 5.0 * math.sin(7.0 * angle)
        lines.append(f"G1 X{radius * math.cos(angle):.4f} Y{radius * math.sin(angle):.4f}")
    lines.append("M30")
    path.write_text("\n".join(lines) + "\n")


def best_of(fn: Callable[[], T]) -> tuple[float, float, T]:
    """(best CPU seconds, best wall seconds, the last run's result) over REPEATS runs."""

    def timed() -> tuple[float, float, T]:
        wall, cpu = time.perf_counter(), time.process_time()
        result = fn()
        return time.process_time() - cpu, time.perf_counter() - wall, result

    runs = [timed() for _ in range(REPEATS)]
    return min(r[0] for r in runs), min(r[1] for r in runs), runs[-1][2]


def main() -> None:
    config = load_nc_config(ROOT / "config" / "axis_default.yaml")
    with tempfile.TemporaryDirectory() as tmp:
        program = Path(tmp) / "bench.ngc"
        write_program(program, N_MOVES)
        text = program.read_text()
        lines = text.splitlines()

        start = time.perf_counter()
        plan_program("G1 X1 F100\nG2 X2 Y0 R1\nG4 P0.1\nG0 X0\nM2", config)
        compile_s = time.perf_counter() - start

        plan_s, plan_wall_s, traj = best_of(lambda: plan_program(program, config))
        raster_s, raster_wall_s, _ = best_of(lambda: plan_program(RASTER, config))
        raster_samples = len(plan_program(RASTER, config))
        raster_moves = sum(1 for line in RASTER.read_text().splitlines() if line.startswith("G1"))

        def lex_all() -> int:
            return sum(
                1
                for number, line in enumerate(lines, 1)
                if lex_line(line, number, file="bench", block_delete=True) is not None
            )

        def lex_and_interpret() -> int:
            interpreter = Interpreter(config, file="bench")
            count = 0
            for number, line in enumerate(lines, 1):
                block = lex_line(line, number, file="bench", block_delete=True)
                if block is not None:
                    count += len(interpreter.block(block))
            return count

        def gcodeparser_all() -> int:
            return sum(1 for _ in gcodeparser.parse_gcode_lines(text))

        lex_s, _, n_lexed = best_of(lex_all)
        interpret_s, _, _ = best_of(lex_and_interpret)
        other_s, _, n_other = best_of(gcodeparser_all)

    figures = {
        "moves": N_MOVES,
        "blocks_per_second": round(N_MOVES / plan_s),
        "blocks_per_second_wall": round(N_MOVES / plan_wall_s),
        "plan_cpu_s": round(plan_s, 3),
        "samples": len(traj),
        "program_time_s": round(float(traj.t_s[-1]), 3),
        "parse_lines_per_second": round(len(lines) / lex_s),
        "parse_interpret_lines_per_second": round(len(lines) / interpret_s),
        "gcodeparser_lines_per_second": round(len(lines) / other_s),
        "parse_ratio_vs_gcodeparser": round(other_s / lex_s, 2),
        "blocks_parsed": n_lexed,
        "blocks_parsed_by_gcodeparser": n_other,
        "numba_first_call_s": round(compile_s, 2),
        "raster_moves": raster_moves,
        "raster_blocks_per_second": round(raster_moves / raster_s),
        "raster_blocks_per_second_wall": round(raster_moves / raster_wall_s),
        "raster_samples": raster_samples,
    }
    for key, value in figures.items():
        print(f"{key:34s} {value}")
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
