"""`toffe-deploy eval`: (being built)."""
from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("eval", help="(being built)")
    p.set_defaults(func=lambda args: 2)
