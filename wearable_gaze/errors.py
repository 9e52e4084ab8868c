"""Errors a user can fix. The CLI prints their message as one line and exits with status 2."""


class UserError(Exception):
    """Bad input at a boundary (a file, an option, a device): the message says what is wrong and
    how to fix it."""
