"""docs/api.md from the public surface's docstrings: `python -m services.api._reference > docs/api.md`
(tests/test_api_surface.py fails when the file is not what this prints)."""

from __future__ import annotations

import inspect

import services.api as api

HEADER = """# Python API reference

Generated from the docstrings of `services.api` (`python -m services.api._reference > docs/api.md`);
`tests/test_api_surface.py` fails when this page and the code differ. Start from the examples in
`examples/`, each run by `make test`. Everything not listed here is private.

"""


def _signature(obj: object) -> str:
    try:
        return str(inspect.signature(obj))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return "(...)"


def _doc(obj: object) -> str:
    return inspect.cleandoc(obj.__doc__ or "").strip()


def reference() -> str:
    """The whole page, one section per public name, in the order of `__all__`."""
    out = [HEADER]
    for name in api.__all__:
        obj = getattr(api, name)
        kind = "exception" if isinstance(obj, type) and issubclass(obj, BaseException) else "class"
        out.append(f"## `{name}` ({kind}, from `{obj.__module__}`)\n\n{_doc(obj)}\n")
        if obj.__module__.startswith("services.api"):
            for attr, member in vars(obj).items():
                if attr.startswith("_") or not (callable(member) or isinstance(member, (property, classmethod))):
                    continue
                fn = member.__func__ if isinstance(member, classmethod) else member
                sig = "" if isinstance(member, property) else _signature(getattr(obj, attr))
                out.append(f"- `{name}.{attr}{sig}`: {_doc(fn).replace(chr(10), ' ')}\n")
        out.append("")
    return "\n".join(out).rstrip() + "\n"


if __name__ == "__main__":
    print(reference(), end="")
