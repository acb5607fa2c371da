"""Command modules of the ``mpipe`` command line, one per subcommand."""


def add_fingering_option(parser) -> None:
    """Add ``--fingering NAME``: which of the calibration's fingerings is played."""
    parser.add_argument(
        "--fingering",
        metavar="NAME",
        help="the fingering played, a name of the calibration's 'fingerings' (default: its "
        "'fingering'); its holes are open, the others closed",
    )
