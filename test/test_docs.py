"""The documentation stays true: generated reference pages equal what the code generates, the README stays short and
points only at files that exist, and nothing cites a file outside the repository."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from hydro_ros.tooling.docgen import BEGIN, END, PAGES, expected_pages, with_results
from test.conftest import REPO


def test_the_reference_pages_and_the_result_tables_are_what_the_code_and_bench_results_generate():
    for page, text in expected_pages(REPO / "docs").items():
        assert page.read_text() == text, f"{page}: run `make docs`"


def test_a_result_block_shows_its_result_file_as_it_is(tmp_path, monkeypatch):
    from hydro_ros.tooling import benchresults

    monkeypatch.setattr(benchresults, "RESULTS", tmp_path)
    (tmp_path / "fdi_eval.md").write_text("| fault | delay |\n|---|---|\n| leak | 12.0 |\n")
    page = "Prose.\n<!-- BEGIN RESULT fdi_eval.md (make docs) -->\n| fault | delay |\n| leak | 11.0 |\n<!-- END RESULT -->\nMore.\n"
    assert with_results(page) == ("Prose.\n<!-- BEGIN RESULT fdi_eval.md (make docs) -->\n\n| fault | delay |\n|---|---|\n| leak | 12.0 |\n"
                                  "\n<!-- END RESULT -->\nMore.\n")
    assert "`mems.md` is not in bench/results: run `make bench`" in with_results(page.replace("fdi_eval.md", "mems.md"))


def test_the_readme_is_short_and_its_links_lead_somewhere():
    readme = (REPO / "README.md").read_text()
    assert len(readme.splitlines()) <= 250
    docs = list((REPO / "docs").rglob("*.md"))
    for page in [REPO / "README.md", *docs]:
        for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", page.read_text()):
            assert (page.parent / target).exists(), f"{page.relative_to(REPO)} links to {target}, which does not exist"


def test_the_architecture_page_names_every_module_and_only_modules_that_exist():
    """docs/architecture.md's layout table against the tree: each folder's row names every module in it, and a module
    a row names (``x.py``) is in that folder, or a path from the package or the repository."""
    rows = [re.match(r"^\| [^|]+ \| (`hydro_ros/[^|]+) \| (.*) \|$", line) for line in (REPO / "docs" / "architecture.md").read_text().splitlines()]
    rows = [row for row in rows if row]
    assert len(rows) >= 10
    for row in rows:
        tokens = set(re.findall(r"`([A-Za-z_][\w/]*(?:\.py)?)`", row.group(2)))
        for folder in (REPO / f for f in re.findall(r"`(hydro_ros/[^`]*/)`", row.group(1))):
            modules = {p.relative_to(folder).as_posix() for p in folder.rglob("*.py") if p.name not in ("__init__.py", "__main__.py")}
            unnamed = sorted(m for m in modules if m not in tokens and m[:-3] not in tokens)
            assert not unnamed, f"docs/architecture.md: {folder.name}'s row does not name {', '.join(unnamed)}"
            absent = sorted(t for t in tokens if t.endswith(".py") and t not in modules and not (REPO / "hydro_ros" / t).exists()
                            and not (REPO / t).exists() and not (REPO / "test" / t).exists())
            assert not absent, f"docs/architecture.md: {folder.name}'s row names {', '.join(absent)}, which is not in the tree"


# Pointers into what the authors read and the package does not ship: the thesis as a plain-text file cited by its line
# numbers, and private digests of it (the fdi, dp and contract notes beside it, cited by their sections and claims). The
# package cites the thesis by its papers P-I ... P-VI (their sections, tables, equations, figures and appendices) and its
# own chapters, and its own files. Each pattern is spelled so that this file does not match it.
UNSHIPPED = {
    "the folders of the notes and of the thesis text": re.compile("shared/" + "(?:spec|seeds)"),
    "the nominal SAM notes": re.compile("sam_" + "nominal"),
    # a section, claim or item of a digest, one named in the possessive or with "the"; not hashlib's hexdigest,
    # hmac's compare_digest or a variable named so
    "a digest citation": re.compile(r"\bthe\s+digests?\b|\bdigests?(?:'s\b|\s+(?:sections?\b|§|claims?\b|appendix\b|#?\d))",
                                    re.IGNORECASE),
    "a digest file": re.compile(r"\b(?:fdi|dp|contract)\.md\b"),
    "the contract notes' sections (docs/interface.md has the same numbering)": re.compile(r"\bcontract\s+(?:sections?|§)\s*\d",
                                                                                           re.IGNORECASE),
    # an L and three to five digits, alone or as a range of two; not L/min, the link lengths L1..L3 or CAN ids (0x...)
    "a line number of the thesis text": re.compile(r"\bL\d{3,5}\b"),
}
CITING = ("README.md", "docs/**/*.md", "hydro_ros/**/*.py", "config/**/*.yaml", "bench/*.py", "bench/results/*.md",
          "launch/*.py", "scripts/*.py", "test/**/*.py", "test/**/*.yaml", "package.xml", "setup.py", "Makefile")


def test_nothing_cites_files_the_repository_does_not_ship():
    paths = sorted({path for pattern in CITING for path in REPO.glob(pattern) if path.is_file()})
    assert len(paths) > 100 and REPO / "docs" / "monitoring.md" in paths and REPO / "config" / "k70m.yaml" in paths
    found = []
    for path in paths:
        text = path.read_text()  # whole, so that a citation broken over two lines is found too
        found += [f"{path.relative_to(REPO)}:{text.count(chr(10), 0, match.start()) + 1}: {what}: {match.group(0)!r}"
                  for what, pattern in UNSHIPPED.items() for match in pattern.finditer(text)
                  if what != "a digest file" or not (REPO / "docs" / match.group(0)).exists()]
    assert not found, "cite the papers (P-I ... P-VI), the thesis's chapters or the package's own files:\n" + "\n".join(found)


def test_make_bench_refuses_a_tree_whose_code_differs_from_its_commit(monkeypatch):
    from hydro_ros.tooling import benchresults, benchrun

    monkeypatch.setattr(benchrun, "run_step", lambda step, code: pytest.fail(f"{step.name} ran on a dirty tree"))
    monkeypatch.setattr(benchresults, "commit", lambda: "abc1234+changes")
    with pytest.raises(SystemExit, match=r"uncommitted changes outside bench/results, docs/ and README.md .*ALLOW_DIRTY=1"):
        benchrun.main(["--only", "mems"])
    monkeypatch.setattr(benchresults, "commit", lambda: "abc1234")
    benchresults.require_clean_tree()
    recipe = (REPO / "Makefile").read_text().split("\nbench:")[1].split("\n\n")[0]
    assert "$(PY) -m hydro_ros.tooling.benchrun $(if $(filter 1,$(ALLOW_DIRTY)),--allow-dirty)" in recipe


def test_a_benchmark_result_carries_its_commit_and_the_page_says_what_a_run_did_not_write(tmp_path, monkeypatch):
    from hydro_ros.tooling import benchresults

    assert benchresults.RESULTS == REPO / "bench" / "results" and len(benchresults.read_results()) >= 20  # the pages read these

    written = json.loads(benchresults.write_result(tmp_path / "crane_cpu.json", {"commit": "typed", "cylinders": 3}).read_text())
    assert written["commit"] == benchresults.commit() != "typed" and written["cylinders"] == 3
    monkeypatch.setattr(benchresults, "RESULTS", tmp_path)
    row = next(line for line in benchresults.benchmarks_markdown().splitlines() if "`crane_cpu.json`" in line)
    assert "not in bench/results (no 'sample_blocks')" in row and written["commit"] in row


def test_a_reproduction_row_says_what_a_run_did_not_write(tmp_path, monkeypatch):
    from hydro_ros.tooling import benchresults
    from hydro_ros.tooling.reproduction import reproduction_markdown

    (tmp_path / "commissioning.json").write_text(json.dumps({"commit": "abc1234", "plants": 6}))
    monkeypatch.setattr(benchresults, "RESULTS", tmp_path)
    rows = reproduction_markdown().splitlines()
    threshold = next(line for line in rows if "implemented as configuration" in line)
    assert "not in bench/results (no 'threshold')" in threshold and "`commissioning.json` (abc1234)" in threshold
    smallest = next(line for line in rows if "smallest detectable leaks" in line)
    assert "not in bench/results (no `fdi_eval.json`)" in smallest and "`fdi_eval.json` (-)" in smallest


def test_every_test_the_reproduction_page_names_exists():
    from hydro_ros.tooling.reproduction import CLAIMS, RESEARCH_PROBLEMS

    for test in (test for entry in (*CLAIMS, *RESEARCH_PROBLEMS) for test in entry.tests):
        path, _, function = test.partition("::")
        assert f"def {function}(" in (REPO / "test" / path).read_text(), f"docs/reproduction.md names {test}, which does not exist"


# a figure of the prose: a number with a decimal point, or a whole number of per cent or times
FIGURE = re.compile(r"(?<![\w.,\-/§])(?<!Section )[-+\u2212]?(\d+\.\d+(?:e[-+]?\d+)?(?!\d|\.\d)|\d+(?=\s?(?:%|x\b|\u00d7)))"
                    r"(\s?(?:%|x\b|\u00d7|kJ|MJ|J\b|kN|MPa|L/min|ms|s\b|min\b|h\b|rad|mm|m\b|Hz|MB))?")
PROSE = re.compile(r"<!-- figures no result file holds[^:]*:(.*?)-->", re.S)


def _figures(text: str) -> list[str]:
    """The figures of a page's prose and tables, as written ("16.8 s", "1.050 x"): code, link targets and comments out."""
    for code in (r"```.*?```", r"`[^`]*`", r"\]\([^)]*\)", r"<!--.*?-->"):
        text = re.sub(code, " ", text, flags=re.S)
    text = re.sub(r"(?<=\d)[-\u2013](?=\d)", " to ", text)  # a range's two ends are two figures
    return [" ".join(m.group(0).replace("\u2212", "-").split()) for m in FIGURE.finditer(text)]


def _values(text: str) -> set[float]:
    return {abs(float(number)) for number in re.findall(r"\d+(?:\.\d+)?(?:e[-+]?\d+)?", text)}


def _scaled(figure: str) -> tuple[float, ...]:
    """What a result file may hold for a figure: itself, a share for a per cent, joules for kJ."""
    return {"%": (1.0, 0.01), "kJ": (1.0, 1e3), "MJ": (1.0, 1e6)}.get(figure.split(" ")[-1].lstrip("0123456789.+-"), (1.0,))


def unbacked_figures(page: str, results: Path, generated: str = "") -> list[str]:
    """The figures of a page that no result file named in their paragraph (else their section, else the page) holds, nor
    the ``generated`` part of the page, at the precision written, less the page's marked prose list (``<!-- figures no
    result file holds (whose): 2.5 s (why); ... -->``); and the list's entries the page does not show."""
    def named(text: str) -> set[str]:
        text = re.sub(r"\]\([^)]*\)|docs/[\w/.-]+", " ", text)  # a link or a docs page names no result
        return {name for name in re.findall(r"[\w-]+\.(?:json|md)\b", text) if (results / name).is_file()}

    read: dict[str, set[float]] = {}  # each named file read once

    def values(files: set[str]) -> set[float]:
        return set().union(_values(generated), *(read.setdefault(name, _values((results / name).read_text())) for name in files))

    prose = {entry.split(" (")[0].strip() for listed in PROSE.findall(page) for entry in listed.split(";") if entry.strip()}
    everywhere, shown, unbacked = named(page), [], []
    for section in re.split(r"\n(?=#+ )", page):
        in_section = named(section) or everywhere
        for paragraph in re.split(r"\n\s*\n", section):
            figures = _figures(paragraph)
            if not figures:
                continue
            # the files the paragraph names, else its section's, else the page's: the nearer the fewer chance matches
            held_values = values(named(paragraph) or in_section)
            for figure in figures:
                shown.append(figure)
                number = re.match(r"[-+]?(\d+(?:\.(\d+))?)(?:e([-+]?\d+))?", figure)
                exponent = 10.0 ** int(number.group(3) or 0)
                target, half_step = float(number.group(1)) * exponent, (0.5 * 10.0 ** -len(number.group(2) or "") + 1e-9) * exponent
                held = any(abs(v - target * scale) <= half_step * scale for v in held_values for scale in _scaled(figure))
                if figure not in prose and not held:
                    unbacked.append(figure)
    return unbacked + [f"{entry} (listed, not shown)" for entry in sorted(prose - set(shown))]


def test_a_figure_no_result_file_holds_is_caught_unless_the_page_lists_it(tmp_path):
    (tmp_path / "dp.json").write_text(json.dumps({"energy_j": 35548.0, "above": 0.0504, "notes": "best at 356 x 201"}))
    page = "DP (LS) gives 35.55 kJ, 5.0 % above, on a 356 x 201 grid (`dp.json`); P-VI's 1.186 x."
    assert unbacked_figures(page, tmp_path) == ["1.186 x"]
    assert unbacked_figures(page.replace("35.55", "35.56"), tmp_path) == ["35.56 kJ", "1.186 x"]
    assert unbacked_figures(page.replace("`dp.json`", "a run"), tmp_path) == ["35.55 kJ", "5.0 %", "356 x", "1.186 x"]
    listed = page + "\n<!-- figures no result file holds (the thesis's): 1.186 x (P-VI); 2.5 s -->"
    assert unbacked_figures(listed, tmp_path) == ["2.5 s (listed, not shown)"]


def test_every_figure_in_the_readme_and_the_hand_written_docs_is_held_by_a_result_file_the_page_names_or_listed_as_prose():
    """What the code generates (PAGES' marked parts, the result blocks) reads bench/results/ itself; every other figure must
    be in a result file its paragraph, section or page names, or in the page's marked list: the thesis's figures, a
    config's or a design value, arithmetic on figures beside it, and what a run typed by hand left (each said so). The
    check is as strong as the files named are small: a figure moved by one in its last digit equals another number of
    the same file about half the time (measured on these pages); a figure typed with no result behind it is caught
    unless it happens to equal one."""
    results = REPO / "bench" / "results"
    pages = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
    assert len(pages) >= 15
    for page in pages:
        text, generated = page.read_text(), ""
        if page.parent != REPO and page.relative_to(REPO / "docs").as_posix() in PAGES:  # the prose around what the code generates
            generated = text.split(BEGIN)[1].split(END)[0]
            text = text.split(BEGIN)[0] + text.split(END)[-1]
        unbacked = unbacked_figures(text, results, generated)
        assert not unbacked, f"{page.relative_to(REPO)}: {'; '.join(unbacked)}: no result file the page names holds these"
