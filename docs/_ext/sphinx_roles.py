"""Griffe extension for the documentation build: the package's docstrings use Sphinx roles and doctest lines.

mkdocstrings renders docstrings as Markdown, where ``:class:`~a.b.C``` would show the role's name and the tilde.
This rewrites, after the package is loaded and before anything is rendered:

* a role (``:class:``, ``:func:``, ``:meth:``, ``:mod:``, ``:attr:``, ``:data:``, ``:obj:``, ``:exc:``) into an
  optional cross-reference to the named object: a link where the API reference renders that object, the name in
  code where it does not (optional references never fail a strict build). ``~`` shows the last component, and
  ``title <target>`` the title; a bare or relative name is resolved in the docstring's module.
* a run of ``>>>`` lines into a ``pycon`` code block (Markdown would read them as nested quotes).

The source files are not changed; only what the documentation shows.
"""

from __future__ import annotations

import html
import re

import griffe

_ROLE = re.compile(r":(?:class|func|meth|mod|attr|data|obj|exc):`([^`]+)`")
_TITLED = re.compile(r"^(?P<title>.*?)\s*<(?P<target>[^<>]+)>$", re.DOTALL)


def _resolve(name: str, obj: griffe.Object) -> str:
    """The full dotted path that ``name`` (absolute, relative ``.x`` or bare ``x.y``) names, seen from ``obj``:
    looked up in the object, then in each enclosing class and module."""
    module = obj if obj.is_module else obj.module
    if name.startswith("."):
        base = module.path if module.is_init_module else module.path.rpartition(".")[0]
        level = len(name) - len(name.lstrip("."))
        for _ in range(level - 1):
            base = base.rpartition(".")[0]
        return f"{base}.{name.lstrip('.')}"
    head, _, rest = name.partition(".")
    scope = obj
    while scope is not None:  # the object itself, its class, its module, its package
        if head in scope.members:
            member = scope.members[head]
            path = member.target_path if member.is_alias else member.path
            return f"{path}.{rest}" if rest else path
        scope = scope.parent
    return name


def _reference(match: re.Match, obj: griffe.Object) -> str:
    text = " ".join(match.group(1).split())
    titled = _TITLED.match(text)
    if titled:
        title, target = titled["title"], titled["target"].strip()
    else:
        target = text.lstrip("~")
        title = target.rpartition(".")[2] if text.startswith("~") else target
    identifier = _resolve(target, obj).rstrip("()")
    return (f'<autoref identifier="{html.escape(identifier)}" optional>'
            f"<code>{html.escape(title)}</code></autoref>")


def _doctest_blocks(text: str) -> str:
    lines, out, block = text.split("\n"), [], []
    for line in lines + [""]:
        if line.lstrip().startswith(">>>") or (block and line.lstrip().startswith("...")):
            block.append(line.strip())
            continue
        if block:
            out += ["```pycon", *block, "```"]
            block = []
        out.append(line)
    return "\n".join(out[:-1])


class SphinxRoles(griffe.Extension):
    """Rewrite every docstring of a loaded package (see the module docstring)."""

    def on_package(self, *, pkg: griffe.Module, **kwargs) -> None:
        self._rewrite(pkg, set())

    def _rewrite(self, obj: griffe.Object, seen: set[str]) -> None:
        if obj.path in seen:
            return
        seen.add(obj.path)
        if obj.docstring is not None:
            value = _ROLE.sub(lambda match: _reference(match, obj), obj.docstring.value)
            obj.docstring.value = _doctest_blocks(value)
        for member in obj.members.values():
            if not member.is_alias:
                self._rewrite(member, seen)
