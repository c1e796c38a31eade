"""The error type users see: a bad input, reported as one line and exit code 2; a bad option
names its field, or on the command line its flag."""

import re


class UserError(ValueError):
    """A problem with what the user asked for (name, file, range, budget), not a bug."""


class OptionError(UserError):
    """A bad option: the message names options by their field (`search_seeds`); `as_flags` names
    them as the command line spells them (`--search-seeds`)."""

    def __init__(self, message: str, *names: str):
        super().__init__(message)
        self.names = names

    def as_flags(self, spelled: dict[str, str] | None = None) -> str:
        """The message with each option named by its flag (`spelled`: flags not made by `flag`)."""
        return flags_in(str(self), self.names, spelled)


def flags_in(text: str, names, spelled: dict[str, str] | None = None) -> str:
    """`text` with each of the option `names` written as its flag."""
    for name in names:
        text = re.sub(rf"(?<![\w-]){name}(?![\w-])", (spelled or {}).get(name, flag(name)), text)
    return text


def flag(name: str) -> str:
    return "--" + name.replace("_", "-")
