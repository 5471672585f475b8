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
