"""`toffe-deploy train`: (being built)."""
from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("train", help="(being built)")
    p.set_defaults(func=lambda args: 2)
