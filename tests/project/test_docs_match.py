"""The docs say what the code does: the keys of `decoded(i)`, no smoke times nobody re-measured."""

from __future__ import annotations

import re
from pathlib import Path

from htdata.format.table import MEMBERS

ROOT = Path(__file__).resolve().parents[2]


def decoded_keys() -> set[str]:
    """The fields a decoded sample holds: one per member kind (rgb, tactile, bend, raw, meta)."""
    return {m.field for m in MEMBERS}


def test_readme_and_format_list_every_decoded_key():
    assert decoded_keys() == {"rgb", "tactile", "bend", "raw", "meta"}
    readme = (ROOT / "README.md").read_text()
    block = readme[readme.index("ds.decoded(0)"):]
    block = block[:block.index("\n\n")]              # the comment lines under the call
    assert set(re.findall(r'"(\w+)":', block)) == decoded_keys()
    fmt = (ROOT / "docs/FORMAT.md").read_text()
    para = fmt[fmt.index("`.decoded(i) -> dict`"):]
    para = para[:para.index("`.episode_range")]
    assert {k for k in decoded_keys() if re.search(rf"\b{k}\b", para)} == decoded_keys()


def test_handtouch_doc_quotes_no_unmeasured_smoke_times():
    text = (ROOT / "docs/HANDTOUCH.md").read_text()
    section = text[text.index("**Verdicts.**"):]
    section = section[:section.index("Configs are plain TOML")]
    assert not re.search(r"\b\d+ s\b", section), "smoke wall times belong to a measured run (results.json meta.seconds)"


def test_every_readme_example_is_run_by_the_install_check():
    """tools/readme_examples.sh (run by `make install-check` against the installed wheel) runs each
    `htdata ...` line of the README's worked examples as written (s3:// is checked for its missing-backend line)."""
    readme = (ROOT / "README.md").read_text()
    block = readme[readme.index("## A worked example per command"):]
    block = block[block.index("```bash"):]
    block = block[:block.index("```", 7)]
    examples = [line.split("#")[0].strip() for line in block.splitlines() if line.startswith("htdata ")]
    script = (ROOT / "tools/readme_examples.sh").read_text().replace('"$HT" ', "htdata ")
    assert len(examples) >= 13
    for example in examples:
        assert example in script, f"README example not run by tools/readme_examples.sh: {example}"
    assert "ds.decoded(0)" in script and "memory://bucket/my-dataset" in script
    assert "readme_examples.sh" in (ROOT / "tools/install_check.sh").read_text()


def test_design_stays_short_names_every_package_and_its_recipes_name_real_files():
    """docs/DESIGN.md is the contract (under 10,000 characters: the detail lives beside the code); its table
    names every package, every package says what it may import, and every file its recipes name exists."""
    text = (ROOT / "docs/DESIGN.md").read_text()
    assert len(text) < 10_000, f"docs/DESIGN.md is {len(text)} characters: move detail to the docs beside it"
    table = text[text.index("| package |"):text.index("## Layering")]
    packages = sorted(p.parent.name for p in (ROOT / "htdata").glob("*/__init__.py"))
    assert [p for p in packages if f"`{p}/`" not in table] == []
    inits = sorted((ROOT / "htdata").rglob("__init__.py")) + sorted((ROOT / "handtouch").rglob("__init__.py"))
    assert [str(p.relative_to(ROOT)) for p in inits if "May import" not in p.read_text()] == []
    recipes = text[text.index("## How to add"):]
    named = {n.rstrip(".,;:)") for n in re.findall(r"(?:htdata|handtouch|tests|schemas|pipelines)/[\w/.<>]+", recipes)}
    packages_re = "|".join(packages)   # a path inside htdata named from its package ("synthetic/corpus.py")
    named |= {f"htdata/{n}" for n in re.findall(rf"(?<![\w/])((?:{packages_re})/[\w/]+\.py)", recipes)}
    named = {n for n in named if "<name>" not in n}     # a template: the new format's own files
    assert named and [n for n in named if not (ROOT / n).exists()] == []
    assert "htdata/ingest/frame.py" in recipes and "NewVersion" in recipes
