"""The docs say what the code is: every module path, `from X import Y` snippet, repo file path and `worldsplat`
command (with its flags) cited in README.md, CONTRIBUTING.md, web/docs/*.md and the model cards resolves; and no
tracked text outside CHANGELOG.md names its history by work-session, issue number or training round ("session 11",
"issue 12", "the v9 prior"): history is CHANGELOG.md's. Format versions (".wsplat v2", "SPZ v4", scenario version 2)
are names, not history, and are not flagged."""

from __future__ import annotations

import argparse
import importlib
import re
import subprocess
from functools import cache
from pathlib import Path

import pytest

from worldsplat.cli import COMMANDS, build_parser
from worldsplat.core.paths import source_root

ROOT = source_root()


def doc_files() -> list[Path]:
    docs = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "web" / "docs").glob("*.md"))]
    docs += sorted((ROOT / "models" / "weights").glob("MODEL_CARD*.md"))
    return [d for d in docs if d.is_file()]


def code_spans(text: str) -> list[str]:
    """Inline `code` spans and the lines of fenced code blocks: where the docs cite code and commands."""
    spans: list[str] = []
    fenced = False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if fenced or line.startswith("    "):
            spans.append(line)
        else:
            spans += re.findall(r"`([^`]+)`", line)
    return spans


# ---------------------------------------------------------------------------------------------------------------
# (a) module paths, imported names, file paths, commands


DOTTED = re.compile(r"(?<![\w./-])(worldsplat_models|worldsplat)((?:\.[A-Za-z_]\w*)+)")
FROM_IMPORT = re.compile(r"from\s+((?:worldsplat_models|worldsplat)(?:\.\w+)*)\s+import\s+\(?([\w ,]+)\)?")
FILE_SUFFIXES = {"json", "md", "py", "wsplat", "ply", "txt"}
LINK = re.compile(r"\]\(([^)\s]+)\)")
TOP_DIRS = ("server/", "models/", "wasm/", "web/", "tests/", "package-config/", ".ci/")


def resolve_dotted(name: str) -> bool:
    """A dotted name resolves when its longest importable prefix is a module and the rest are attributes of it."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def cited_names() -> list[tuple[str, str]]:
    """(doc, dotted name) for every worldsplat / worldsplat_models dotted name the docs cite."""
    out = []
    for doc in doc_files():
        for m in DOTTED.finditer(doc.read_text()):
            name = m.group(1) + m.group(2)
            if name.rsplit(".", 1)[-1] not in FILE_SUFFIXES:  # `worldsplat.json` is a file the export writes
                out.append((doc.name, name))
    return sorted(set(out))


def cited_imports() -> list[tuple[str, str, str]]:
    out = []
    for doc in doc_files():
        for m in FROM_IMPORT.finditer(doc.read_text()):
            for name in m.group(2).split(","):
                name = name.strip().split(" as ")[0].strip()
                if name:
                    out.append((doc.name, m.group(1), name))
    return sorted(set(out))


def cited_paths() -> list[tuple[str, str]]:
    """(doc, path) for repo paths in code spans (from the repository root) and in Markdown links (from the doc)."""
    out = []
    for doc in doc_files():
        text = doc.read_text()
        for target in LINK.findall(text):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            path = (doc.parent / target.split("#")[0]).resolve()
            out.append((doc.name, str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)))
        for span in code_spans(text):
            for token in re.findall(
                r"(?<![\w./-])((?:\.ci|server|models|wasm|web|tests|package-config)/[\w./*<>{}$-]+)", span
            ):
                token = token.rstrip(".")
                if any(c in token for c in "*<>{}$") or re.search(r"/(X|NAME|N|DIR|OUT)\b", token):
                    continue  # a pattern or placeholder, not a file
                out.append((doc.name, token))
    return sorted(set(out))


# Paths the docs name that set-up, a build or a test run derives (git-ignored, absent in a fresh clone).
DERIVED = ("models/weights/onnx", "web/pkg", "wasm/target", "package-config/node_modules", "tests/artifacts")


def repo_path_exists(p: str) -> bool:
    """From the repository root, or (`tests/x.rs`, `src/x.rs` as the viewer page cites them) inside a Rust crate."""
    if (ROOT / p).exists() or any(p.startswith(d) for d in DERIVED):
        return True
    return p.startswith(("tests/", "src/")) and any((ROOT / "wasm" / "crates").glob(f"*/{p}"))


def test_docs_are_found():
    assert len(doc_files()) >= 10
    assert len(cited_names()) >= 30 and len(cited_paths()) >= 30 and len(cited_commands()) >= 15


def test_cited_module_paths_resolve():
    bad = [f"{doc}: {name}" for doc, name in cited_names() if not resolve_dotted(name)]
    assert not bad, "module paths cited in the docs that do not resolve:\n" + "\n".join(bad)


def test_cited_imports_resolve():
    bad = []
    for doc, module, name in cited_imports():
        try:
            mod = importlib.import_module(module)
        except ImportError:
            bad.append(f"{doc}: from {module} import {name} (no module)")
            continue
        if not hasattr(mod, name):
            try:
                importlib.import_module(f"{module}.{name}")
            except ImportError:
                bad.append(f"{doc}: from {module} import {name}")
    assert not bad, "imports cited in the docs that fail:\n" + "\n".join(bad)


def test_cited_repo_paths_exist():
    bad = [f"{doc}: {p}" for doc, p in cited_paths() if not repo_path_exists(p)]
    assert not bad, "repo paths cited in the docs that do not exist:\n" + "\n".join(bad)


COMMAND = re.compile(r"(?:^|[\s`(/])worldsplat ((?:[a-z][a-z-]*)(?: [^|;&`]*)?)")


def cited_commands() -> list[tuple[str, str, list[str]]]:
    """(doc, sub-command words, flags) for every `worldsplat SUB ...` in a code span or block."""
    out = []
    for doc in doc_files():
        for span in code_spans(doc.read_text()):
            for m in COMMAND.finditer(span):
                words = m.group(1).split()
                flags = sorted({re.match(r"--[a-z][\w-]*", w).group(0) for w in words if re.match(r"--[a-z]", w)})
                out.append((doc.name, words, flags))
    return out


@cache
def sub_parser(name: str) -> argparse.ArgumentParser:
    parser = build_parser(only=name)
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices[name]


def parser_flags(parser: argparse.ArgumentParser, words: list[str]) -> set[str]:
    """The option strings of the parser a command line reaches (descending into nested sub-commands)."""
    flags = {o for a in parser._actions for o in a.option_strings}
    nested = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if nested and words and words[0] in nested[0].choices:
        flags |= parser_flags(nested[0].choices[words[0]], words[1:])
    elif nested:  # a flag of any nested command is accepted when the doc does not name which one
        for p in nested[0].choices.values():
            flags |= {o for a in p._actions for o in a.option_strings}
    return flags


def test_cited_commands_exist_with_their_flags():
    bad = []
    for doc, words, flags in cited_commands():
        name = words[0]
        if name not in COMMANDS:
            bad.append(f"{doc}: worldsplat {' '.join(words)} (no sub-command {name!r})")
            continue
        known = parser_flags(sub_parser(name), words[1:])
        missing = [f for f in flags if f not in known]
        if missing:
            bad.append(f"{doc}: worldsplat {name}: unknown flags {missing}")
    assert not bad, "commands cited in the docs that the CLI does not have:\n" + "\n".join(bad)


# ---------------------------------------------------------------------------------------------------------------
# (b) no history labels outside CHANGELOG.md

ROUND_NOUNS = (
    r"weights|stack|vae|dits?|prior|decoders?|enhancer|campaign|models?|generator|training|pixel mix|served|set"
)
LABEL_PATTERNS = [
    r"\bsessions?[ -]?\d+",  # "session 11", "session-1 model", "sessions 14-15"
    r"\bissues?[ -]#?\d+",  # "issue 12", "issue #7"
    r"\brounds?[ -]\d+",  # "round 9"
    r"\bv(?:[5-9]|1\d)\b",  # v5..v19: training rounds (no format named here has reached version 5)
    r"\bv\d+-v\d+\b",  # a range of rounds: "v4-v8"
    r"\.md\W{1,3}v\d",  # a doc section named by round: models.md "v4"
]
LABEL = re.compile("|".join(f"(?:{p})" for p in LABEL_PATTERNS), re.IGNORECASE)
# "the v2 VAE", "v2/v3 stack", "v11 weights", "the v1 set"; not on a line about the .wsplat format ("v1 + v2 decoder")
ROUND_NOUN = re.compile(rf"\bv\d+(?:/v\d+)*(?:'s)? (?:{ROUND_NOUNS})\b", re.IGNORECASE)
WSPLAT_LINE = re.compile(r"wsplat", re.IGNORECASE)
# v3 / v4 name training rounds too, but also format versions (Niantic SPZ's, .wsplat v3): flagged on lines that are
# not about SPZ or .wsplat, outside the files of those formats.
ROUND_V34 = re.compile(r"\bv[34]\b")
SPZ_LINE = re.compile(r"spz|ngsp", re.IGNORECASE)
# A file named by round: test_models_v2.py, campaign_v4_test0.png (not format versions: wsplat-v2.md, bad_v2_*.wsplat).
PATH_LABEL = re.compile(
    r"(?:models|inference|campaign|dit|prior|vae|decoder|enhancer|eval|weights)(?:_\w+)?[_-]v\d+|session|issue_?\d",
    re.IGNORECASE,
)


def label_hits(line: str, path: str = "") -> list[str]:
    """The history labels in one line of text; `path` gives the file's own context (an SPZ reader's v3 / v4)."""
    hits = [m.group(0) for m in LABEL.finditer(line)]
    if not WSPLAT_LINE.search(line):
        hits += [m.group(0) for m in ROUND_NOUN.finditer(line)]
    formats = (SPZ_LINE, WSPLAT_LINE)
    if not any(f.search(line) or f.search(path) for f in formats):
        hits += [m.group(0) for m in ROUND_V34.finditer(line)]
    return hits


@pytest.mark.parametrize(
    "text",
    [
        "since session 11, the v11 weights",
        "the session-1 model and the session-2 pairs",
        "Sessions 14-15 asked",
        "refinement (issue 7)",
        "issue #12 item 6",
        "round 9 of training",
        "the v9 prior",
        "the v2 VAE",
        "the whole v2/v3 stack",
        "a v4 DiT",
        "what the v4-v8 models read",
        'models.md "v6" item 2',
        "(web/docs/models.md v5's per-pixel one)",
        "layout at the input (v3)",
    ],
)
def test_label_lint_flags_history_labels(text):
    assert label_hits(text), text


@pytest.mark.parametrize(
    "text",
    [
        "the server writes .wsplat v2 (zstd byte planes)",
        "a v1 file and a v2 chunk",
        "Progressive .wsplat v1 + v2 decoder",
        "wsplat-v1.md and wsplat-v2.md",
        "scenario version 2; v1 files are migrated on load",
        "a v2 scenario with explicit agents",
        "Niantic SPZ: v3 written, v4 read",
        "'NGSP' (v4) or a gzip stream (v2/v3)",
        "--version v1.0-mini-like",
        "the session's checks; an InferenceSession",
        "one issue with two cores",
    ],
)
def test_label_lint_passes_format_versions(text):
    assert not label_hits(text), text


def test_label_lint_reads_an_spz_files_versions_as_formats():
    assert not label_hits("the gzip stream of a v2/v3 file", "server/worldsplat/gaussians/spz.py")
    assert label_hits("the gzip stream of a v2/v3 file", "server/worldsplat/pipeline/inference.py")


def test_label_lint_reads_wsplat_v3_as_a_format():
    assert not label_hits("a .wsplat v3 file's agent objects")
    assert not label_hits("v3: an OBJC chunk", "server/worldsplat/gaussians/wsplat/decoder.py")
    assert label_hits("v3: the prior", "server/worldsplat/pipeline/inference.py")


# CHANGELOG.md is where history is named; this file holds the lint's own examples of what it flags.
LINT_EXEMPT = ("CHANGELOG.md", "tests/python/test_docs.py")


def tracked_files() -> list[str]:
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    return [p for p in out.decode().split("\0") if p and p not in LINT_EXEMPT]


def test_no_history_labels_in_tracked_text():
    hits = []
    for rel in tracked_files():
        if PATH_LABEL.search(Path(rel).name):
            hits.append(f"{rel}: file name")
        path = ROOT / rel
        if not path.is_file() or path.stat().st_size > 2_000_000:
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue  # binary
        for n, line in enumerate(text.splitlines(), 1):
            found = label_hits(line, rel)
            if found:
                hits.append(f"{rel}:{n}: {found}")
    assert not hits, f"{len(hits)} history labels outside CHANGELOG.md:\n" + "\n".join(hits[:200])
