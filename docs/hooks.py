"""mkdocs hooks for the API pages (mkdocs.yml: ``hooks``).

The docstrings are written in the numpy style with Sphinx roles
(``:func:`name```) and reStructuredText literal blocks (``text::``), which
Markdown shows as written. These hooks show a role as its code alone and
end the paragraph before a literal block with one colon. They change only
the built HTML, not the docstrings.
"""

import re

_ROLE = re.compile(r":(?:func|class|meth|mod|data|attr|exc|obj):(?=<code>)")
_LITERAL = re.compile(r"::</p>(\s*<div class=\"highlight\">)")


def on_page_content(html, **kwargs):
    html = _ROLE.sub("", html)
    return _LITERAL.sub(r":</p>\1", html)
