"""Throughput of `rfmp-convert`'s readers: frames (steps) per second, one section per source.

    OMP_NUM_THREADS=1 .venv/bin/python recipes/benchmarks/conversion_throughput.py \\
        [--out results/conversion_throughput.md] [--repeats 3]

LeRobot: a dataset generated here (2 episodes x 300 frames at 30 fps, one 96x96 camera as an
mp4 video (libx264, yuv420p) or as PNG images in the parquet, a 3-D state and a 2-D action),
written in format v3.0 (both episodes in one parquet and one mp4) and v2.1 (one file per
episode). Each row times `read_lerobot` (tables, video decoding and nearest-frame matching),
then the whole conversion (read, fill the memory-mapped store, save it). The median and the
fastest wall-clock rates of ``--repeats`` runs after one warm-up are reported, and the rate per
CPU-second (process time of all threads), which other jobs on a shared machine disturb least.

The results file starts with the command that wrote it; each source is one ``section_*``
function returning its Markdown lines, listed in ``SECTIONS``.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from rfmp_rl.data.lerobot import read_lerobot
from rfmp_rl.data.store import DemonstrationStore

ROOT = Path(__file__).resolve().parents[2]


def _load_lerobot_fixture():
    """tests/data/lerobot_fixture.py, the LeRobot dataset writer of the tests, as a module."""
    path = ROOT / "tests" / "data" / "lerobot_fixture.py"
    spec = importlib.util.spec_from_file_location("lerobot_fixture", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module

CAMERA = "observation.images.top"


def timings(fn: Callable[[], object], repeats: int) -> tuple[float, float, float]:
    """Median and fastest wall-clock seconds, and median CPU seconds (all threads of this
    process), of ``repeats`` runs after a warm-up."""
    fn()  # warm-up
    wall, cpu = [], []
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return statistics.median(wall), min(wall), statistics.median(cpu)


def section_lerobot(repeats: int, episodes: int = 2, frames: int = 300, size: int = 96,
                    fps: int = 30) -> list[str]:
    """LeRobot conversion: frames per second by format version and camera storage."""
    import av
    import pyarrow
    fixture = _load_lerobot_fixture()
    make_episodes, write_lerobot = fixture.make_episodes, fixture.write_lerobot

    lines = [
        "## LeRobot",
        "",
        f"{episodes} episodes x {frames} frames, one {size}x{size} RGB camera, {fps} fps; "
        f"PyAV {av.__version__} (FFmpeg decoders, default threading), pyarrow "
        f"{pyarrow.__version__}. *read*: `read_lerobot` alone; *convert*: read + "
        "`DemonstrationStore.from_episodes` + `save` (what `rfmp-convert lerobot` does).",
        "",
        "| format | camera stored as | frames | read: frames/s (median / fastest) | read: "
        "frames per CPU-second | convert: frames/s (median / fastest) | convert: frames per "
        "CPU-second |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    total = episodes * frames
    with tempfile.TemporaryDirectory() as tmp:
        for version in ("v3.0", "v2.1"):
            for stored in ("mp4 video", "PNG in parquet"):
                video = stored == "mp4 video"
                data = make_episodes([frames] * episodes, fps, size=size,
                                     video_key=CAMERA if video else None,
                                     image_key=None if video else CAMERA)
                root = Path(tmp) / f"{version}-{'video' if video else 'png'}"
                write_lerobot(root, data, version=version, fps=fps,
                              video_keys=[CAMERA] if video else [],
                              image_keys=[] if video else [CAMERA])
                read, read_best, read_cpu = timings(lambda root=root: read_lerobot(root),
                                                    repeats)
                out = Path(tmp) / "store"

                def convert(root=root, out=out):
                    eps, manifest = read_lerobot(root)
                    DemonstrationStore.from_episodes(eps, manifest, memmap=True).save(out)

                full, full_best, full_cpu = timings(convert, repeats)
                lines.append(f"| {version} | {stored} | {total} | {total / read:.0f} / "
                             f"{total / read_best:.0f} | {total / read_cpu:.0f} | "
                             f"{total / full:.0f} / {total / full_best:.0f} | "
                             f"{total / full_cpu:.0f} |")
                print(lines[-1], flush=True)
    return lines + [""]


SECTIONS: dict[str, Callable[[int], list[str]]] = {"lerobot": section_lerobot}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "conversion_throughput.md")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sections", nargs="+", default=list(SECTIONS), choices=list(SECTIONS))
    args = parser.parse_args()
    script = Path(__file__).resolve().relative_to(ROOT)
    threads = os.environ.get("OMP_NUM_THREADS")
    command = (f"{'OMP_NUM_THREADS=' + threads + ' ' if threads else ''}.venv/bin/python "
               f"{script} {' '.join(sys.argv[1:])}").strip()
    lines = [
        command,
        "",
        "# Conversion throughput",
        "",
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python "
        f"{platform.python_version()}; {args.repeats} runs after a warm-up.",
        "",
    ]
    for name in args.sections:
        lines += SECTIONS[name](args.repeats)
    load = os.getloadavg()[0]
    lines += [f"Load average (1 min) at the end of the run: {load:.1f} on {os.cpu_count()} cores "
              "(with other jobs on the machine the wall-clock rates vary several-fold between "
              "runs; the per-CPU-second rates vary least).", ""]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
