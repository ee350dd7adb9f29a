"""sweep_feet.py's foot and no-pop rules on variants of the shared clips (a report).

Variants that no exporter here wrote: other frame rates and feet without toes.

    python benchmarks/sweep_variants.py [--clip SUBSTR ...] [--target SUBSTR ...]
                                        [--rates 24,30,60,120] [--toeless] [--out DIR]

Each clip of ``../shared/data`` (``--clip`` filters by name) is written again, by the engine's
own BVH writer, resampled to each of ``--rates`` (slerp between frames; a rate the clip
already has is skipped), and with ``--toeless`` also with its toe joints cut off (each foot's
toe, found as the engine finds feet, becomes its ankle's End Site at the toe's offset, and
its channels and those of the joints below it are dropped: a capture exported to the
ankle). Every variant is solved onto every character (``--target`` filters) exactly as
sweep_feet.py solves a pair, and printed as its row. The variants go to ``--out`` (a
temporary directory by default, removed after).

Stop 57 found two faults this way that the shared clips at their own rates did not show: a
walk at 120 fps whose toe was let go a frame before the other heel landed (the hips popped
1.85 times the limit; contacts._back_to_back), and toe-less feet whose held orientation put
the character's toe under its floor (goals missed by 12-55 degrees).
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SHARED_DATA, prepare  # noqa: E402

prepare()

import argparse  # noqa: E402
import tempfile  # noqa: E402


def without_toes(text: str, toes: set[str]) -> str:
    """BVH ``text`` with the joints named in ``toes`` (and everything below them) cut off:
    each becomes an End Site at its own offset, and its channels and those below it leave
    every frame's row."""
    lines = text.splitlines()
    motion = next(i for i, line in enumerate(lines) if line.strip() == "MOTION")
    head, out, drop, column, i = lines[:motion], [], set(), 0, 0
    while i < len(head):
        words = head[i].split()
        if words[:1] == ["JOINT"] and words[1] in toes:
            indent = head[i][:len(head[i]) - len(head[i].lstrip())]
            offset = next(h.strip() for h in head[i + 1:] if h.split()[:1] == ["OFFSET"])
            depth, j = 0, i + 1
            while True:                                   # the joint's block, children too
                if head[j].split()[:1] == ["CHANNELS"]:
                    n = int(head[j].split()[1])
                    drop.update(range(column, column + n))
                    column += n
                depth += head[j].count("{") - head[j].count("}")
                j += 1
                if depth == 0:
                    break
            out += [f"{indent}End Site", f"{indent}{{", f"{indent}\t{offset}", f"{indent}}}"]
            i = j
            continue
        if words[:1] == ["CHANNELS"]:
            column += int(words[1])
        out.append(head[i])
        i += 1
    rows = []
    for line in lines[motion:]:
        values = line.split()
        if len(values) == column:
            rows.append(" ".join(v for k, v in enumerate(values) if k not in drop))
        else:
            rows.append(line)
    return "\n".join(out + rows) + "\n"


def variants(clip: Path, rates: list[float], toeless: bool, out: Path) -> list[Path]:
    """The variant files of ``clip`` written into ``out``."""
    from motion_composer.engine.correction.contacts import find_feet
    from motion_composer.engine.formats import read_performer, write_bvh
    motion = read_performer(clip)
    made = []
    for fps in rates:
        if abs(fps - motion.fps) > 1e-3 * fps:
            path = out / f"{clip.stem}_{fps:g}fps.bvh"
            write_bvh(motion.resampled(fps), path)
            made.append(path)
    if toeless:
        toes = {t for _, t in find_feet(motion.skeleton) if t}
        if toes:
            path = out / f"{clip.stem}_toeless.bvh"
            path.write_text(without_toes(clip.read_text(errors="replace"), toes))
            made.append(path)
    return made


def main() -> None:
    import sweep_feet
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sweep_feet.add_filters(parser)
    parser.add_argument("--rates", default="30,120",
                        help="frame rates to resample to, comma-separated (default 30,120)")
    parser.add_argument("--toeless", action="store_true", help="also cut the toes off")
    parser.add_argument("--out", help="write the variants here (kept)")
    args = parser.parse_args()
    rates = [float(r) for r in args.rates.split(",") if r.strip()]
    clips, targets, _ = sweep_feet.clips_and_targets()
    clips = [c for c in clips if c.parent == SHARED_DATA
             and (not args.clip or any(s in c.name for s in args.clip))]
    targets = [t for t in targets if not args.target or any(s in t.name for s in args.target)]
    with tempfile.TemporaryDirectory() as scratch:
        out = Path(args.out or scratch)
        out.mkdir(parents=True, exist_ok=True)
        for clip in clips:
            for variant in variants(clip, rates, args.toeless, out):
                for target in targets:
                    print(sweep_feet.format_row(sweep_feet.solve_pair(variant, target)),
                          flush=True)


if __name__ == "__main__":
    main()
