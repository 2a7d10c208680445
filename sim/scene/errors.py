"""The one error type of scene loading: a file that cannot be used, named down to object and field."""

from __future__ import annotations

from pathlib import Path


class SceneFileError(Exception):
    """A scene file that cannot be used. ``str()`` is one sentence fit for a user.

    ``path`` is the offending file (or folder), ``obj`` the object's name when one object is at
    fault (``'#3'`` when the entry has no usable name), ``field`` the dotted field path.
    """

    def __init__(
        self, path: Path | str, message: str, *, obj: str | None = None, field: str | None = None
    ):
        self.path = str(path)
        self.obj = None if obj is None else one_line(obj, 80)
        self.field = None if field is None else one_line(field, 80)
        self.message = message
        where = self.path
        if self.obj is not None:
            where += f": object '{self.obj}'"
        if self.field is not None:
            where += f", field '{self.field}'" if self.obj is not None else f": field '{self.field}'"
        super().__init__(f"{where}: {one_line(message)}")


def one_line(text: str, limit: int = 300) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."
