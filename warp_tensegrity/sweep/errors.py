"""The sweep's errors (a leaf module: every sweep module may raise them)."""

from __future__ import annotations

from ..options import OptionError


class SpecError(OptionError):
    """Invalid sweep spec. ``errors`` lists one message per problem, each naming the key path."""

    def __init__(self, errors, source: str | None = None):
        if isinstance(errors, str):
            errors = [errors]
        self.errors = list(errors)
        self.source = source
        head = f"invalid sweep spec{f' {source}' if source else ''}"
        if len(self.errors) == 1:
            msg = f"{head}: {self.errors[0]}"
        else:
            msg = f"{head} ({len(self.errors)} problems):\n" + "\n".join(f"  - {e}" for e in self.errors)
        ValueError.__init__(self, msg)


class SweepError(RuntimeError):
    """A sweep cannot run, resume or combine as asked; the message says what to do."""
