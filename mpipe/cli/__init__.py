"""The ``mpipe`` command line, the demo and the shipped example; the top layer.

Modules
-------
main
    The parser and the entry point ``mpipe``.
commands
    One module per subcommand, each exposing ``add_parser(subparsers)``.
demo
    ``make demo``: the whole pipeline on the shipped example, beside the truth.
virtual_takes
    Virtual takes with known truth (what ``mpipe synth-take`` writes).

Examples
--------
    The shipped example take.
"""
