"""Exceptions raised for bad user input."""


class ConfigError(ValueError):
    """Invalid user input (a parameter, a name, a path). The message names the culprit.

    The CLI turns it into a one-line message and exit code 2.
    """


def unknown_name(kind: str, name: str, known, *, otherwise: str = "") -> str:
    """The message for an unknown ``name``: the closest known one when it looks like a typo
    (difflib), else every known name and then ``otherwise`` (", or ..."). ``kind`` says what
    was looked for ("unknown integrator", "scene 'cloth' has no parameter")."""
    import difflib

    known = list(known)
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.75)
    if close:
        return f"{kind} {name!r}: did you mean {close[0]!r}? (all {len(known)}: `taichi-sim list`)"
    return f"{kind} {name!r} (choose from {', '.join(known)}{otherwise})"


class InputWarning(UserWarning):
    """Input that is used, but perhaps not as meant (a mesh with non-manifold edges, several
    pieces, or triangles removed on loading). The CLI prints each as one line on stderr."""
