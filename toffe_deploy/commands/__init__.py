"""One module per sub-command. Each has ``register(subparsers)``, which adds its parser and sets
``func`` to a handler ``func(args) -> int``. Heavy imports (torch, Lava) live inside handlers so
that ``toffe-deploy --help`` and the lean runtime stay fast and torch-free."""

COMMAND_MODULES = ("events", "dataset", "train", "eval", "export", "run")
