"""sweep_feet.py's foot and no-pop rules on variants of the shared clips (a report).

Variants that no exporter here wrote: other frame rates, feet without toes, a capture's
noise and a floor away from zero.

    python benchmarks/sweep_variants.py [--clip SUBSTR ...] [--target SUBSTR ...]
                                        [--rates 24,30,60,120] [--toeless]
                                        [--jitter MM,DEG] [--lift M] [--turn DEG]
                                        [--out DIR]

Each clip of ``../shared/data`` (``--clip`` filters by name) is written again, by the engine's
own BVH writer, resampled to each of ``--rates`` (slerp between frames; a rate the clip
already has is skipped), and with ``--toeless`` also with its toe joints cut off (each foot's
toe, found as the engine finds feet, becomes its ankle's End Site at the toe's offset, and
its channels and those of the joints below it are dropped: a capture exported to the
ankle), with ``--jitter MM,DEG`` also with a raw capture's noise (the root moved by
Gaussian noise of MM millimetres on each axis and every joint turned about a random axis by
Gaussian noise of DEG degrees, each frame on its own, seeded), and with ``--lift M`` also
raised by M metres (a capture whose floor is not at zero; negative lowers), and with
``--turn DEG`` also turned about the vertical through the origin (a capture walking another
way). Every variant is solved onto every character (``--target`` filters) exactly as
sweep_feet.py solves a pair, and printed as its row. The variants go to ``--out`` (a
temporary directory by default, removed after).

Stop 57 found two faults this way that the shared clips at their own rates did not show: a
walk at 120 fps whose toe was let go a frame before the other heel landed (the hips popped
1.85 times the limit; contacts._back_to_back), and toe-less feet whose held orientation put
the character's toe under its floor (goals missed by 12-55 degrees). Stop 58 found with
``--jitter`` that a capture's noise broke its plants into pieces (the CMU 131 walk with 2 mm
and 0.3 degrees onto the Mixamo mannequin popped 1.77 times the limit; the Bandai walk's
goals were missed by up to 8 mm): a noisy capture's foot paths are now smoothed
(contacts.NOISY).
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


def jittered(motion, mm: float, deg: float, seed: int = 0):
    """``motion`` with a raw capture's noise: the root moved by Gaussian noise of ``mm``
    millimetres per axis, every joint turned by Gaussian noise of ``deg`` degrees about a
    random axis, each frame drawn on its own."""
    import numpy as np
    from motion_composer.engine.quaternions import from_rotvec, qmul
    rng = np.random.default_rng(seed)
    F, J, _ = motion.rotations.shape
    axis = rng.normal(size=(F, J, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = np.radians(deg) * rng.normal(size=(F, J, 1))
    rotations = qmul(motion.rotations, from_rotvec(axis * angle))
    translations = motion.translations.copy()
    translations[:, 0] += 1e-3 * mm * rng.normal(size=(F, 3))
    return motion.replace(rotations=rotations, translations=translations)


def lifted(motion, metres: float):
    """``motion`` raised by ``metres`` (its root's height moved; the engine's axes are
    Y-up)."""
    translations = motion.translations.copy()
    translations[:, 0, 1] += metres
    return motion.replace(translations=translations)


def turned(motion, degrees: float):
    """``motion`` turned by ``degrees`` about the vertical (the engine's +Y) through the
    origin: the root's rotation and its path."""
    import numpy as np
    from motion_composer.engine.quaternions import about_axis, qmul, qrot
    turn = about_axis(np.array([0.0, 1.0, 0.0]), np.radians(degrees))
    rotations = motion.rotations.copy()
    turns = np.broadcast_to(turn, (motion.num_frames, 4))
    rotations[:, 0] = qmul(turns, rotations[:, 0])
    translations = motion.translations.copy()
    translations[:, 0] = qrot(turns, translations[:, 0])
    return motion.replace(rotations=rotations, translations=translations)


def variants(clip: Path, rates: list[float], toeless: bool, out: Path,
             jitter: tuple[float, float] | None = None, lift: float | None = None,
             turn: float | None = None) -> list[Path]:
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
    if jitter:
        path = out / f"{clip.stem}_jitter{jitter[0]:g}mm{jitter[1]:g}deg.bvh"
        write_bvh(jittered(motion, *jitter), path)
        made.append(path)
    if lift:
        path = out / f"{clip.stem}_lift{lift:+g}m.bvh"
        write_bvh(lifted(motion, lift), path)
        made.append(path)
    if turn:
        path = out / f"{clip.stem}_turn{turn:g}deg.bvh"
        write_bvh(turned(motion, turn), path)
        made.append(path)
    return made


def main() -> None:
    import sweep_feet
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sweep_feet.add_filters(parser)
    parser.add_argument("--rates", default="30,120",
                        help="frame rates to resample to, comma-separated (default 30,120)")
    parser.add_argument("--toeless", action="store_true", help="also cut the toes off")
    parser.add_argument("--jitter", help="also add noise: MM,DEG (root millimetres, joint "
                        "degrees, Gaussian, each frame)")
    parser.add_argument("--lift", type=float, help="also raise the clip by this many metres")
    parser.add_argument("--turn", type=float, help="also turn the clip about the vertical by "
                        "this many degrees")
    parser.add_argument("--out", help="write the variants here (kept)")
    args = parser.parse_args()
    rates = [float(r) for r in args.rates.split(",") if r.strip()]
    jitter = tuple(float(v) for v in args.jitter.split(",")) if args.jitter else None
    clips, targets, _ = sweep_feet.clips_and_targets()
    clips = [c for c in clips if c.parent == SHARED_DATA
             and (not args.clip or any(s in c.name for s in args.clip))]
    targets = [t for t in targets if not args.target or any(s in t.name for s in args.target)]
    with tempfile.TemporaryDirectory() as scratch:
        out = Path(args.out or scratch)
        out.mkdir(parents=True, exist_ok=True)
        for clip in clips:
            for variant in variants(clip, rates, args.toeless, out, jitter, args.lift,
                                    args.turn):
                for target in targets:
                    print(sweep_feet.format_row(sweep_feet.solve_pair(variant, target)),
                          flush=True)


if __name__ == "__main__":
    main()
