"""The seams a newcomer extends state their contracts (docs/DESIGN.md "How to add ..."): Google-style sections.

A public function or method of a module below needs `Args:` when it takes parameters (besides self / cls),
`Returns:` (or `Yields:`) when its body returns or yields a value, `Raises:` when its body raises; a class's
constructor arguments go in the class docstring (or `__init__`'s). `Args:` names every parameter (`*args`,
`**kwargs` as written or bare). Properties and private names are left out. A missing section, or a parameter
the section leaves out, is found here, not by the next reader of the code.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
# module -> the public classes checked in it (None: the whole module)
SEAMS = {
    "htdata/source/adapters/base.py": None,       # the adapter contract
    "htdata/write/repack.py": None,               # repack
    "htdata/store/snapshot.py": None,             # snapshot and commit_parts
    "htdata/format/shardio.py": ("ShardWriter",),  # the shard writer
    "htdata/glove/normalisesettings.py": None,    # the normaliser's config as a pipeline gives it
    "htdata/format/codec.py": None,               # the codec registry and the codecs of members not maps
    "htdata/format/tactilecodec.py": None,        # the tactile value rule and the EXR codec
    "htdata/glove/normalise.py": None,            # the normaliser
    "htdata/glove/normaliseconfig.py": None,      # and its config
}
SECTIONS = {"Args": ("Args:",), "Returns": ("Returns:", "Yields:"), "Raises": ("Raises:",)}


def _own_nodes(fn: ast.AST):
    """The nodes of `fn`'s body, not those of a function or class defined inside it."""
    stack = list(fn.body)
    while stack:
        node = stack.pop()
        yield node
        stack.extend(c for c in ast.iter_child_nodes(node)
                     if not isinstance(c, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda)))


def parameters(fn: ast.FunctionDef, method: bool) -> list[str]:
    """`fn`'s parameters (self / cls of a method left out)."""
    a = fn.args
    params = [p.arg for p in a.posonlyargs + a.args + a.kwonlyargs] + [p.arg for p in (a.vararg, a.kwarg) if p]
    return params[1:] if method and params[:1] in (["self"], ["cls"]) else params


_ENTRY = re.compile(r"^\*{0,2}([A-Za-z_]\w*)\s*(\([^)]*\))?:")


def args_named(doc: str) -> set[str]:
    """The names the `Args:` sections of `doc` describe (an entry: `name:` or `name (type):` one indent in)."""
    names, lines = set(), doc.splitlines()
    for i, line in enumerate(lines):
        if line.strip() != "Args:":
            continue
        indent, entry = len(line) - len(line.lstrip()), None
        for body in lines[i + 1:]:
            if not body.strip():
                continue
            depth = len(body) - len(body.lstrip())
            if depth <= indent:
                break
            entry = depth if entry is None else entry
            if depth == entry and (m := _ENTRY.match(body.strip())):
                names.add(m.group(1))
    return names


def needed(fn: ast.FunctionDef, method: bool) -> set[str]:
    """The sections `fn`'s docstring needs."""
    params = parameters(fn, method)
    nodes = list(_own_nodes(fn))
    returns = any(isinstance(n, ast.Return) and n.value is not None
                  and not (isinstance(n.value, ast.Constant) and n.value.value is None) for n in nodes)
    yields = any(isinstance(n, (ast.Yield, ast.YieldFrom)) for n in nodes)
    raises = any(isinstance(n, ast.Raise) and n.exc is not None for n in nodes)   # a bare re-raise passes one on
    return {s for s, need in (("Args", params), ("Returns", returns or yields), ("Raises", raises)) if need}


def _lacks(fn: ast.FunctionDef, where: str, doc: str, method: bool) -> list[str]:
    out = [f"{where}:{fn.lineno}: no {s}" for s in sorted(needed(fn, method))
           if not any(word in doc for word in SECTIONS[s])]
    if "Args" in needed(fn, method) and "Args:" in doc:
        named = args_named(doc)
        out += [f"{where}:{fn.lineno}: Args leaves out {p}" for p in parameters(fn, method) if p not in named]
    return out


def missing_sections(source: str, where: str, classes: set[str] | None = None) -> list[str]:
    """`where:line: no SECTION` for each section a public function or method of `source` lacks."""
    out = []
    for node in ast.parse(source).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and classes is None \
                and not node.name.startswith("_"):
            out += _lacks(node, f"{where} {node.name}", ast.get_docstring(node) or "", False)
        elif isinstance(node, ast.ClassDef) and not node.name.startswith("_") \
                and (classes is None or node.name in classes):
            for m in node.body:
                if not isinstance(m, (ast.FunctionDef, ast.AsyncFunctionDef)) or \
                        any(isinstance(d, ast.Name) and d.id == "property" for d in m.decorator_list):
                    continue
                if m.name == "__init__":
                    doc = (ast.get_docstring(node) or "") + (ast.get_docstring(m) or "")
                    out += _lacks(m, f"{where} {node.name}()", doc, True)
                elif not m.name.startswith("_"):
                    out += _lacks(m, f"{where} {node.name}.{m.name}", ast.get_docstring(m) or "", True)
    return out


@pytest.mark.parametrize("module", sorted(SEAMS))
def test_the_seams_state_their_contracts(module):
    classes = SEAMS[module]
    lacking = missing_sections((ROOT / module).read_text(), module, None if classes is None else set(classes))
    assert not lacking, f"public functions without the docstring sections their contract needs: {lacking}"


def test_missing_sections_finds_each_missing_section():
    source = '''
def plain():
    """Nothing to say."""

def takes(x):
    """Takes x."""
    if x:
        raise ValueError(x)
    return x

def documented(x):
    """Takes x.

    Args:
        x: a thing.

    Returns:
        x.
    """
    return x

def _private(x):
    return x

class Thing:
    """A thing."""

    def __init__(self, size):
        self.size = size

    @property
    def area(self):
        return self.size ** 2

    def grow(self):
        """Grows."""
        yield self.size

    def reraise(self):
        """Passes an error on."""
        try:
            pass
        except OSError:
            raise
'''
    assert missing_sections(source, "m") == [
        "m takes:5: no Args", "m takes:5: no Raises", "m takes:5: no Returns",
        "m Thing():28: no Args", "m Thing.grow:35: no Returns"]
    assert missing_sections(source, "m", classes={"Other"}) == []


def test_missing_sections_finds_a_parameter_args_leaves_out():
    source = '''
def partly(x, y, *rest, flag=False, **options):
    """Takes x and y.

    Args:
        x: a thing.
          y: a continuation line, not an entry.
        flag (bool): a switch.
        **options: the rest.

    Returns:
        x.
    """
    return x

def wholly(x, y=1):
    """Takes both.

    Args:
        x: a thing.
        y: another.
    """

class Thing:
    """A thing.

    Args:
        size: how big.
    """

    def __init__(self, size, colour):
        """Builds it.

        Args:
            colour: which.
        """
'''
    assert missing_sections(source, "m") == ["m partly:2: Args leaves out y", "m partly:2: Args leaves out rest"]
    assert missing_sections(source.replace("        colour: which.", "        hue: which."), "m") == [
        "m partly:2: Args leaves out y", "m partly:2: Args leaves out rest", "m Thing():31: Args leaves out colour"]
