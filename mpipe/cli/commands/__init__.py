"""Command modules of the ``mpipe`` command line, one per subcommand."""

from __future__ import annotations

from dataclasses import replace

from mpipe.core.errors import UserError
from mpipe.measurement.calibration import load_calibration, per_note


def add_fingering_option(parser, per_note: bool = True) -> None:
    """Add ``--fingering``: which of the calibration's fingerings is played.

    ``per_note`` False (``impedance``, ``simulate``, ``synth-take``: no take to choose
    from): the option takes one name, and ``auto`` or a list is refused by
    :func:`load_one_fingering`.
    """
    if per_note:
        text = (
            "the fingering played, a name of the calibration's 'fingerings' (default: its "
            "'fingering'); its holes are open, the others closed. 'auto': each note's found "
            "among them (the default when the file names fingerings but no default one); "
            "A,B,...: one per note"
        )
    else:
        text = (
            "the fingering played, one name of the calibration's 'fingerings' (default: its "
            "'fingering'; without one, every hole closed); its holes are open, the others "
            "closed ('auto' and lists need a take to choose from: mpipe run/separate)"
        )
    parser.add_argument("--fingering", metavar="NAME", help=text)


def load_one_fingering(path, fingering: str | None, what: str):
    """The calibration at ``path`` playing one fingering, for a command with no take.

    ``auto`` and a list ``A,B`` choose a fingering per note of a take; ``impedance``,
    ``simulate`` and ``synth-take`` have none, and would play every hole closed. They are
    refused here; a file whose default is missing (or per note) plays every hole closed
    and its ``fingering`` is None, so that no copy of it names ``auto`` or a list.

    Raises
    ------
    UserError
        For ``auto`` or a list, naming the option and what ``what`` (the command) expects.
    """
    if per_note(fingering):
        raise UserError(
            f"--fingering {fingering}: {what} plays one fingering; expected one name of "
            f"{path}'s fingerings ('auto' and lists choose per note of a take: mpipe run)"
        )
    cal = load_calibration(path, fingering)
    return replace(cal, fingering=None) if per_note(cal.fingering) else cal
