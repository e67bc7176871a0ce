"""Exceptions raised for bad user input."""


class ConfigError(ValueError):
    """Invalid user input (a parameter, a name, a path). The message names the culprit.

    The CLI turns it into a one-line message and exit code 2.
    """


def unknown_name(kind: str, name: str, known, *, otherwise: str = "") -> str:
    """The message for an unknown ``name``: the closest known ones when it looks like a typo,
    else every known name and then ``otherwise`` (", or ..."). ``kind`` says what was looked
    for ("unknown integrator", "scene 'cloth' has no parameter")."""
    known = list(known)
    close = close_names(name, known)
    if close:
        listed = " or ".join(", ".join(repr(c) for c in close).rsplit(", ", 1))
        return f"{kind} {name!r}: did you mean {listed}? (all {len(known)}: `taichi-sim list`)"
    return f"{kind} {name!r} (choose from {', '.join(known)}{otherwise})"


def close_names(name: str, known: list[str]) -> list[str]:
    """The known names ``name`` may be a typo of: the closest by difflib's ratio; else those
    with two neighbouring letters swapped (``vdb``: the ratio of three-letter names is too low
    to tell); else those it begins, when it is long enough to mean something (``implicit``:
    the three implicit methods). Empty when none."""
    import difflib

    close = difflib.get_close_matches(name, known, n=1, cutoff=0.75)
    if close:
        return close
    swapped = [k for k in known if len(k) == len(name) and any(
        name[:i] + name[i + 1] + name[i] + name[i + 2:] == k for i in range(len(name) - 1))]
    if swapped:
        return swapped[:1]
    return [k for k in known if len(name) >= 3 and k.startswith(name)][:4]


class InputWarning(UserWarning):
    """Input that is used, but perhaps not as meant (a mesh with non-manifold edges, several
    pieces, or triangles removed on loading). The CLI prints each as one line on stderr."""


class InputNote(UserWarning):
    """A value the toolkit chose from the input where the user gave none (a mesh cloth's
    self-contact thickness fitted to its rest shape). The CLI prints each as one line on stderr,
    ``taichi-sim: ...``, as it announces its other chosen defaults."""
