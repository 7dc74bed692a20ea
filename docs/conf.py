"""Sphinx configuration of the glossdepth documentation site (``make docs``).

Built with warnings as errors (``sphinx-build -W``, see the Makefile). Pages are Markdown (MyST);
the protocol pages include protocol.md's sections (it stays the single source); the reference
is generated from the code: the command lines from each package's ``build_parser()``
(sphinx-argparse), the API from each package's ``__all__`` (autodoc + numpydoc), design.toml's
keys from its comments (``_ext/designkeys.py``). The pictures come from ``make_pictures.py``.
"""

import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
sys.path.insert(0, str(DOCS.parent))
sys.path.insert(0, str(DOCS / "_ext"))

project = "glossdepth"
author = "the glossdepth lab"
copyright = "2026, the glossdepth lab"

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "numpydoc",
    "sphinxarg.ext",
    "designkeys",
    "apipages",
]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build", "_generated/run", "_auto", "Thumbs.db", ".DS_Store"]
myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3
# protocol.md's sections keep their own heading levels (### under a page's #) when included.
suppress_warnings = ["myst.header"]

# The API reference lists each package's __all__; numpydoc renders the NumPy docstrings.
autodoc_default_options = {"members": True, "undoc-members": False}
autodoc_typehints = "none"
autodoc_member_order = "bysource"
numpydoc_show_class_members = False
numpydoc_validation_checks = set()
numpydoc_xref_param_type = False

html_theme = "pydata_sphinx_theme"
html_title = "glossdepth"
html_theme_options = {
    "navigation_depth": 2,
    "header_links_before_dropdown": 6,
    "show_toc_level": 2,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": [],
}
html_static_path = []


def _laid_out(text: str) -> bool:
    """Text laid out with indented lines (a RawDescriptionHelpFormatter's examples)."""
    return any(line[:1].isspace() for line in text.splitlines()[1:])


def _plain_help(render_list):
    """sphinx-argparse parses each help string as reStructuredText; ours are plain text
    ("sessions/*.csv" would open an emphasis): escape the two characters that mean markup there,
    and show text laid out with indented lines as --help prints it, in a literal block."""
    from docutils import nodes

    def render(items, markdown_help, settings=None):
        out = []
        for item in items:
            if isinstance(item, str) and _laid_out(item):
                out.append(nodes.literal_block(item, item))
            else:
                if isinstance(item, str):
                    item = item.replace("*", r"\*").replace("|", r"\|")
                out += render_list([item], markdown_help, settings)
        return out

    return render


def _laid_out_text(nested_parse_paragraph):
    """The same for a top-level parser's description and epilog."""
    from docutils import nodes

    def parse(self, text):
        if _laid_out(text):
            return nodes.literal_block(text, text)
        return nested_parse_paragraph(self, text)

    return parse


def setup(app):
    import sphinxarg.ext

    sphinxarg.ext.render_list = _plain_help(sphinxarg.ext.render_list)
    directive = sphinxarg.ext.ArgParseDirective
    directive._nested_parse_paragraph = _laid_out_text(directive._nested_parse_paragraph)
smartquotes = False  # "--filter" stays two hyphens in option help
