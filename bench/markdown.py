"""Generated sections of the documentation: blocks between markers, rewritten in place.

``docs/reproduction.md`` holds blocks such as ``<!-- cube:start --> ... <!-- cube:end -->``
that the commands which make the numbers rewrite (``gridflow claims --write-doc``,
``gridflow cube --write-doc``), so that prose stating a result comes from the data.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["replace_block", "rewrite_block"]


def _markers(tag: str) -> tuple[str, str]:
    return f"<!-- {tag}:start -->", f"<!-- {tag}:end -->"


def replace_block(text: str, tag: str, block: str) -> str:
    """``text`` with the block between the ``tag`` markers replaced (or appended)."""
    start, end = _markers(tag)
    body = f"{start}\n\n{block}\n\n{end}"
    if start in text and end in text:
        return text[:text.index(start)] + body + text[text.index(end) + len(end):]
    return text + ("\n" if text else "") + body + "\n"


def rewrite_block(path, tag: str, block: str) -> Path:
    """Rewrite the ``tag`` block of the markdown file ``path`` (atomically; the file is
    created if missing)."""
    from gridflow.io import atomic_write

    path = Path(path)
    text = path.read_text() if path.exists() else ""
    with atomic_write(path, "w") as fh:
        fh.write(replace_block(text, tag, block))
    return path
