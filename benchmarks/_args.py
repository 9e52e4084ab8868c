"""The command line every benchmark has: one size option (trials, frames, sessions, seconds) and a
seed."""

import argparse


def size_and_seed(doc: str, option: str, kind, default, seed: int, what: str) -> argparse.Namespace:
    """Parse ``option`` (e.g. ``--trials``, of type ``kind``, ``what`` it counts) and ``--seed``."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument(option, type=kind, default=default, help=f"{what} (default {default})")
    ap.add_argument("--seed", type=int, default=seed, help=f"random seed (default {seed})")
    return ap.parse_args()
