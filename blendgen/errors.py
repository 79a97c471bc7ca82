"""User-facing errors: the CLI prints them without a traceback and exits with their code."""


class UserError(Exception):
    """A mistake in the user's input (job, recording, arguments). Exit code 2.

    The message names the file, field or frame and what was expected.
    """

    exit_code = 2

    def __init__(self, message: str, *, where: str | None = None):
        self.where = where
        super().__init__(f"{where}: {message}" if where else message)


class StageError(Exception):
    """A stage failed on valid input (e.g. a worker crashed repeatedly). Exit code 1."""

    exit_code = 1
