"""Convert a demonstration source into a `DemonstrationStore` on disk and print its manifest.

Usage::

    python -m rfmp_rl.data.convert dp_zarr ../shared/data/pusht/pusht_cchi_v7_replay.zarr \\
        --out data/pusht_store
    python -m rfmp_rl.data.convert robomimic lift_ph.hdf5 --out data/lift --filter train
    python -m rfmp_rl.data.convert ros bags/ --config topics.yaml --out data/teleop --skip-bad
    python -m rfmp_rl.data.convert lasa LShape,Sine --out data/lasa
    python -m rfmp_rl.data.convert lerobot ~/datasets/pusht --out data/pusht_lerobot \\
        --episodes 0,1,2 --keys observation.state,observation.image=obs/cam
    MINARI_DATASETS_PATH=~/minari python -m rfmp_rl.data.convert minari D4RL/door/human-v2 \\
        --out data/door

(also installed as the ``rfmp-convert`` command). The store folder holds the memory-mapped
steps, ``manifest.json`` and the episode lengths; open it with ``DemonstrationStore.load``.
``--dry-run`` reads and prints the manifest without writing.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tensordict import TensorDict

from rfmp_rl.data.episodes import DataError, Manifest
from rfmp_rl.data.store import check_store_destination

__all__ = ["read_source", "main"]

FORMATS = ("dp_zarr", "robomimic", "ros", "lasa", "lerobot", "minari")

#: The formats that read each option; the others refuse it (an ignored option is a silent
#: wrong result). Minari stores every numeric entry, so it takes no --keys.
_READ_BY = {
    "--keys": ("dp_zarr", "robomimic", "lerobot"),
    "--filter": ("robomimic",),
    "--config": ("ros",),
    "--episodes": ("lerobot", "minari"),
    "--rate": ("dp_zarr", "minari", "ros"),
}

ROS_HELP = """ROS bags: --config names a YAML file that maps topics to keys and sets the control
rate, flat action/observation vectors, and what a gap in a stream does (max_gap_s, on_gap). Every
field is described in rfmp_rl/data/README.md, section "ROS bags: the topic config", and in the
docstring of rfmp_rl.data.ros. --skip-bad skips unreadable bags and lists them at the end and in
the manifest; without it the first unreadable bag stops the conversion. One worked path from a
bag to a trained policy and an exported controller: rfmp_rl/data/README.md, section "From a bag
to a controller".

Quaternions (every reader): each episode's first sample at w >= 0, then sign continuity; keys,
quaternion fields and every bad input with its message: rfmp_rl/data/README.md."""


def read_source(
    fmt: str,
    source: str,
    *,
    keys: list[str] | None = None,
    filter_key: str | None = None,
    config: str | None = None,
    episodes: list[int] | None = None,
    rate_hz: float | None = None,
    skip_bad: bool = False,
    quaternions: str | None = None,
    raw_quaternion_signs: bool = False,
) -> tuple[list[TensorDict], Manifest]:
    """Dispatch to the reader of ``fmt`` (one of `FORMATS`). ``episodes`` selects episodes by
    the source's index (``lerobot``, ``minari``); ``rate_hz`` is the control rate of a source
    that records none (``minari``, ``dp_zarr``) or, for ``ros``, overrides the config's
    ``rate_hz``. An option the format does not read raises `ValueError`.

    ``skip_bad`` (ROS only) skips unreadable bags and lists them in ``manifest.skipped``.
    ``quaternions`` names quaternion fields the reader cannot know (``"action[3:7],obs/q:wxyz"``,
    `rfmp_rl.data.quaternions`); ``raw_quaternion_signs`` keeps the recorded signs of every
    quaternion field, known or named.

    Example:
        >>> eps, manifest = read_source("lasa", "LShape")
        >>> manifest.format, manifest.episodes
        ('lasa', 7)
    """
    given = {"--keys": keys, "--filter": filter_key, "--config": config, "--episodes": episodes,
             "--rate": rate_hz}
    for flag, value in given.items():
        if value is not None and fmt in FORMATS and fmt not in _READ_BY[flag]:
            raise ValueError(f"{fmt}: {flag} is not read by this format (it is read by "
                             f"{', '.join(_READ_BY[flag])} only)")
    if quaternions is not None and fmt in ("ros", "lasa"):
        raise ValueError(f"{fmt}: --quaternions is not read (" + (
            "pose orientations are known from the message types)" if fmt == "ros" else
            "LASA shapes are 2-D positions)"))
    quats = {"quaternions": quaternions, "raw_quaternion_signs": raw_quaternion_signs}
    if fmt == "dp_zarr":
        from rfmp_rl.data.dp_zarr import PUSHT_RATE_HZ, read_dp_zarr

        return read_dp_zarr(source, keys, rate_hz=rate_hz or PUSHT_RATE_HZ, **quats)
    if fmt == "robomimic":
        from rfmp_rl.data.robomimic import read_robomimic

        return read_robomimic(source, obs_keys=keys, filter_key=filter_key, **quats)
    if fmt == "ros":
        from rfmp_rl.data.ros import load_rosbag_config, read_rosbags

        if config is None:
            raise ValueError("ros: --config topics.yaml is required (it maps topics to keys)")
        # A bag, a rosbag2 folder, or a folder of bags (read in name order, one episode each).
        return read_rosbags([source], load_rosbag_config(config), rate_hz=rate_hz,
                            skip_bad=skip_bad, raw_quaternion_signs=raw_quaternion_signs)
    if fmt == "lasa":
        from rfmp_rl.data.lasa import read_lasa

        return read_lasa(source.split(","))
    if fmt == "lerobot":
        from rfmp_rl.data.lerobot import read_lerobot

        return read_lerobot(source, episodes=episodes, keys=keys, **quats)
    if fmt == "minari":
        from rfmp_rl.data.minari import read_minari

        return read_minari(source, episodes=episodes, rate_hz=rate_hz, **quats)
    raise ValueError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")


def _indices(text: str) -> list[int]:
    try:
        indices = [int(part) for part in text.split(",") if part.strip()]
    except ValueError as err:
        raise ValueError(f"--episodes takes comma-separated integers, got {text!r}") from err
    twice = sorted({i for i in indices if indices.count(i) > 1})
    if twice:
        raise ValueError(f"--episodes lists episode {twice[0]} more than once ({text!r})")
    return indices


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="rfmp-convert", description=__doc__.split("\n")[0], epilog=ROS_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("format", choices=FORMATS)
    parser.add_argument("source", help="file, folder, bag(s), LASA shape names (comma-separated) "
                        "or a Minari dataset id")
    parser.add_argument("--out", type=Path, help="store folder to write: missing, empty, or a "
                        "store written before (replaced atomically); anything else is refused")
    parser.add_argument("--keys", help="comma-separated keys to read (zarr arrays / robomimic obs "
                        "/ LeRobot features, each optionally renamed: name=store/key)")
    parser.add_argument("--episodes", help="LeRobot / Minari: comma-separated episode indices")
    parser.add_argument("--rate", type=float, help="control rate in Hz of a source that records "
                        "none (minari; dp_zarr, default 10): timestamps = step / rate; ROS: "
                        "overrides the config's rate_hz")
    parser.add_argument("--filter", dest="filter_key", help="robomimic mask/<filter> split")
    parser.add_argument("--config", help="ROS: the topic config YAML (see below)")
    parser.add_argument("--skip-bad", action="store_true",
                        help="ROS: skip unreadable bags (corrupt, missing topic, gap); list them")
    parser.add_argument("--quaternions", metavar="KEY[a:b][:ORDER],...",
                        help="quaternion fields the reader cannot know, by store key ('a/b'), "
                        "e.g. action[3:7] or obs/q:wxyz (ORDER xyzw, the default, has w last); "
                        "each episode's first sample is put at w >= 0, then signs are made "
                        "continuous. robomimic obs/*quat and ROS orientations always are")
    parser.add_argument("--raw-quaternion-signs", action="store_true",
                        help="keep the recorded quaternion signs (no w >= 0, no continuity)")
    parser.add_argument("--dry-run", action="store_true", help="read and print; write nothing")
    args = parser.parse_args(argv)
    if args.out is None and not args.dry_run:
        parser.error("--out is required unless --dry-run")
    if args.skip_bad and args.format != "ros":
        parser.error("--skip-bad applies to the ros format only")
    try:
        if not args.dry_run:  # before the read: a refused --out costs nothing
            check_store_destination(args.out)
        episodes, manifest = read_source(
            args.format,
            args.source,
            keys=args.keys.split(",") if args.keys else None,
            filter_key=args.filter_key,
            config=args.config,
            episodes=_indices(args.episodes) if args.episodes else None,
            rate_hz=args.rate,
            skip_bad=args.skip_bad,
            quaternions=args.quaternions,
            raw_quaternion_signs=args.raw_quaternion_signs,
        )
    except (DataError, FileNotFoundError, ValueError, ImportError) as err:
        print(f"rfmp-convert: error: {err}", file=sys.stderr)
        return 2
    except (KeyError, TypeError, PermissionError) as err:  # a reader's unforeseen input
        print(f"rfmp-convert: error: cannot read {args.source}: {type(err).__name__}: {err}",
              file=sys.stderr)
        return 2
    print(manifest)
    if not args.dry_run:
        from rfmp_rl.data.store import DemonstrationStore

        try:
            store = DemonstrationStore.from_episodes(episodes, manifest, memmap=True)
            path = store.save(args.out)
        except (DataError, OSError) as err:
            print(f"rfmp-convert: error: {err} (any previous store at {args.out} is unchanged)",
                  file=sys.stderr)
            return 2
        print(f"wrote {path} ({manifest.episodes} episodes, {manifest.steps} steps)")
    bags = [item for item in manifest.skipped if "episode" not in item]
    if bags:
        print(f"skipped {len(bags)} unreadable bag(s):")
        for item in bags:
            print(f"  {item['file']}: {item['reason']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
