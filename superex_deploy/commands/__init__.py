"""The ``superex`` commands, one module each with ``add_arguments(parser)`` and ``run(args) -> int``
(:mod:`superex_deploy.cli` finds them); options shared by several commands are declared and checked once, in
``_options``."""
