"""A griffe extension for the API reference (mkdocs.yml): the docstrings' Sphinx roles become links.

The docstrings cross-reference in Sphinx's words (``:func:`~surrol_data.datasets.metrics.proficiency```), which
mkdocstrings shows as raw text. Each role becomes an optional autorefs cross-reference to the object it names —
its full path as written, or the name resolved against the docstring's own module (or class) — shown as code:
a link where that object is on the site, plain code where it is not (no broken link, no build warning).
"""

from __future__ import annotations

import html
import re

import griffe

ROLE = re.compile(r":(?:py:)?(?:meth|func|class|mod|attr|data|exc|obj|const):`(~?)([^`]+?)`")


def _identifier(name: str, obj: griffe.Object) -> str:
    if name.startswith("surrol_data"):
        return name
    module = obj.module.path if obj.module is not None else obj.path
    if name.startswith("."):
        return module + name
    scope = obj if obj.is_class or obj.is_module else obj.parent
    if scope is not None and scope.is_class and name.split(".")[0] in scope.all_members:
        return f"{scope.path}.{name}"
    return f"{module}.{name}"


def as_links(text: str, obj: griffe.Object) -> str:
    """``text`` with every Sphinx role replaced by an optional cross-reference (see the module doc)."""
    def link(match: re.Match) -> str:
        short, name = match[1] == "~", match[2].strip()
        title = name.rsplit(".", 1)[-1] if short else name.lstrip(".")
        return (f'<autoref identifier="{html.escape(_identifier(name, obj))}" optional>'
                f"<code>{html.escape(title)}</code></autoref>")

    return ROLE.sub(link, text)


class SphinxRoles(griffe.Extension):
    """Rewrites the roles of every loaded docstring (see the module doc)."""

    def on_object(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = as_links(obj.docstring.value, obj)
