"""Facts that the documentation states in more than one place agree with their source: the presets sweep.py
offers, and the status of each results folder."""

import os
import re

import pytest

import sweep
from helpers import REPO

RESULTS = sorted(name for name in os.listdir(os.path.join(REPO, "results"))
                 if os.path.exists(os.path.join(REPO, "results", name, "README.md")))


def read(*parts: str) -> str:
    with open(os.path.join(REPO, *parts), encoding="utf-8") as f:
        return f.read()


def test_docs_tools_lists_every_paper_preset_of_sweep():
    listed = re.search(r"`--paper ([a-z|]+)`", read("docs", "tools.md"))
    assert listed, "docs/tools.md names no --paper list"
    assert sorted(listed.group(1).split("|")) == sorted(sweep.PRESETS)


@pytest.mark.parametrize("folder", RESULTS)
def test_the_docs_index_links_each_results_folder_with_the_status_its_page_gives(folder):
    index = read("docs", "README.md")
    link = f"[results/{folder}](../results/{folder}/README.md)"
    assert link in index
    title = read("results", folder, "README.md").splitlines()[0]
    unfinished = bool(re.search(r"in progress|begun|not finished", title))
    assert (f"{link} (in progress)" in index) == unfinished, (title, "docs/README.md says otherwise")
