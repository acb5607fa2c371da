"""Command modules of the ``mpipe`` command line, one per subcommand."""


def add_fingering_option(parser) -> None:
    """Add ``--fingering NAME|auto|A,B,...``: which of the calibration's fingerings is played."""
    parser.add_argument(
        "--fingering",
        metavar="NAME",
        help="the fingering played, a name of the calibration's 'fingerings' (default: its "
        "'fingering'); its holes are open, the others closed. 'auto': each note's found "
        "among them (the default when the file names fingerings but no default one); "
        "A,B,...: one per note",
    )
