#!/usr/bin/env python3
"""Checks of the workspace's shape that a reviewer would otherwise have to remember
(docs/architecture.md): run by .ci/run, and by hand with `python3 tools/ci/architecture.py`.

- host/ is a folder of crates, not a crate itself (a crate there would hide among the
  others, and the layout could not say what it is).
- Nothing under host/ (the product's libraries) depends on a crate under rig/ (the
  virtual rig, which stands in for hardware): the product must not need its stand-in.
- clap (argument parsing) is a dependency of the command-line crates only (cli/,
  tools/): libraries take typed options, and the CLI parses into them.
- No two modules of a crate import each other, directly or round a circle (each file
  a module; its `crate::`, `super::` and `self::` paths outside comments and test
  modules are its imports): any circle fails.
- No function in the product's code (tests, benches and examples aside) is longer than
  80 lines, but those listed in tools/ci/long-functions.txt: tables and declarations
  that say so, and functions still to be split, each at its length today (a listed
  function may shrink, and its entry then goes; it may not grow).

Reads `cargo metadata`, so the dependencies are the ones cargo resolves, whatever the
manifests' spelling. Exits 1 listing every breach.
"""

import json
import re
import subprocess
import sys
from pathlib import Path

# The longest a function may be, lines from `fn` to its closing brace.
MAX_FUNCTION_LINES = 80


def module_of(src: Path, file: Path) -> tuple:
    """A source file's module path (src/a/b.rs and src/a/b/mod.rs are a::b)."""
    parts = list(file.relative_to(src).with_suffix("").parts)
    if parts == ["lib"] or parts == ["main"]:
        return ()
    if parts[-1] == "mod":
        parts = parts[:-1]
    return tuple(parts)


def imports(module: tuple, text: str, modules: dict) -> set:
    """The other modules a file's `crate::`/`super::`/`self::` paths name."""
    text = re.sub(r"//[^\n]*", "", text)
    text = re.sub(r"#\[cfg\(test\)\]\s*mod \w+\s*\{.*", "", text, flags=re.S)
    found = set()
    for path in re.findall(r"\b((?:crate|super|self)(?:::\w+)+)", text):
        segments = path.split("::")
        if segments[0] == "crate":
            base, rest = (), segments[1:]
        else:
            base, rest = module, segments
            while rest and rest[0] in ("super", "self"):
                base = base[:-1] if rest[0] == "super" else base
                rest = rest[1:]
        for k in range(len(rest), 0, -1):
            named = base + tuple(rest[:k])
            if named in modules:
                if named != module:
                    found.add(named)
                break
    return found


def circles(src: Path) -> list:
    """Groups of modules under `src` that import each other (Tarjan's components)."""
    files = [f for f in src.rglob("*.rs") if not {"tests", "bin"} & set(f.relative_to(src).parts)]
    modules = {module_of(src, f): f for f in files}
    edges = {m: imports(m, f.read_text(), modules) for m, f in modules.items()}
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append({"::".join(m) or "lib" for m in group})

    sys.setrecursionlimit(10_000)
    for v in edges:
        if v not in index:
            visit(v)
    return found


def blank(text: str) -> str:
    """Rust source with comments, strings and char literals blanked to spaces (newlines
    kept, so line numbers hold): braces left are the code's own."""
    out = list(text)
    n = len(text)
    i = 0
    def clear(a, b):
        for k in range(a, b):
            if out[k] != "\n":
                out[k] = " "
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            clear(i, j)
            i = j
        elif text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            clear(i, j)
            i = j
        elif (m := re.compile(r'b?r(#*)"').match(text, i)) and (i == 0 or not (text[i-1].isalnum() or text[i-1] == "_")):
            end = '"' + m.group(1)
            j = text.find(end, m.end())
            j = n if j < 0 else j + len(end)
            clear(m.end(), j - len(end))
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            clear(i + 1, j)
            i = j + 1
        elif c == "'":
            if text.startswith("\\", i + 1):
                j = text.find("'", i + 2)
                clear(i + 1, j)
                i = j + 1
            elif i + 2 < n and text[i + 2] == "'":
                clear(i + 1, i + 2)
                i += 3
            else:
                i += 1
        else:
            i += 1
    return "".join(out)

def test_modules_removed(text: str) -> str:
    """`#[cfg(test)] mod … { … }` blanked (brace-matched)."""
    out = list(text)
    for m in re.finditer(r"#\[cfg\(test\)\]\s*(pub\s+)?mod\s+\w+\s*\{", text):
        depth, j = 1, m.end()
        while j < len(text) and depth:
            depth += {"{": 1, "}": -1}.get(text[j], 0)
            j += 1
        for k in range(m.start(), j):
            if out[k] != "\n":
                out[k] = " "
    return "".join(out)

def functions(text: str):
    """(name, first line, lines) of every fn with a body."""
    code = test_modules_removed(blank(text))
    for m in re.finditer(r"\bfn\s+(\w+)", code):
        j, depth = m.end(), 0
        while j < len(code):
            ch = code[j]
            if ch in "([<":
                depth += 1
            elif ch in ")]>":
                depth -= 1 if code[j-1] != "-" else 0
            elif ch == ";" and depth <= 0:
                j = -1
                break
            elif ch == "{" and depth <= 0:
                break
            j += 1
        if j < 0 or j >= len(code):
            continue
        start, braces = j, 0
        while j < len(code):
            braces += {"{": 1, "}": -1}.get(code[j], 0)
            j += 1
            if braces == 0:
                break
        first = code.count("\n", 0, m.start()) + 1
        last = code.count("\n", 0, j) + 1
        yield m.group(1), first, last - first + 1


def long_functions(root: Path) -> dict:
    """Every function over MAX_FUNCTION_LINES in tracked sources outside tests,
    benches, examples and fuzz targets: {(path, name): lines} (the longest of a name
    in a file)."""
    listed = subprocess.run(
        ["git", "ls-files", "*.rs"], cwd=root, check=True, capture_output=True, text=True
    ).stdout.split()
    found = {}
    for name in listed:
        path = Path(name)
        if {"tests", "benches", "examples", "fuzz"} & set(path.parts):
            continue
        for fn, _, lines in functions((root / path).read_text()):
            if lines > MAX_FUNCTION_LINES:
                key = (name, fn)
                found[key] = max(found.get(key, 0), lines)
    return found


def known_long(root: Path) -> dict:
    """tools/ci/long-functions.txt: `lines path fn  # why`, one per line."""
    known = {}
    for raw in (root / "tools/ci/long-functions.txt").read_text().splitlines():
        line = raw.split("#", 1)[0].strip()
        if line:
            lines, path, fn = line.split()
            known[(path, fn)] = int(lines)
    return known


def length_breaches(root: Path) -> list:
    found, known = long_functions(root), known_long(root)
    breaches = []
    for (path, fn), lines in sorted(found.items()):
        allowed = known.get((path, fn))
        if allowed is None:
            breaches.append(
                f"{path}: fn {fn} is {lines} lines (at most {MAX_FUNCTION_LINES}): split it "
                "into functions that each do one thing, or, for a table or declaration, "
                "list it in tools/ci/long-functions.txt saying so"
            )
        elif lines > allowed:
            breaches.append(
                f"{path}: fn {fn} grew to {lines} lines (listed at {allowed} in "
                "tools/ci/long-functions.txt, to be split): split it rather than grow it"
            )
    for (path, fn), allowed in sorted(known.items()):
        if (path, fn) not in found:
            breaches.append(
                f"tools/ci/long-functions.txt: {path} fn {fn} is no longer over "
                f"{MAX_FUNCTION_LINES} lines (or gone): remove its entry"
            )
        elif found[(path, fn)] < allowed:
            breaches.append(
                f"tools/ci/long-functions.txt: {path} fn {fn} is {found[(path, fn)]} lines "
                f"now, listed at {allowed}: lower its entry, so it cannot grow back"
            )
    return breaches


def main() -> int:
    root = Path(__file__).resolve().parents[2]
    meta = json.loads(
        subprocess.run(
            ["cargo", "metadata", "--format-version", "1", "--no-deps", "--offline"],
            cwd=root, check=True, capture_output=True, text=True,
        ).stdout
    )

    def folder(manifest: str) -> Path:
        return Path(manifest).parent.relative_to(root)

    members = {p["name"]: folder(p["manifest_path"]) for p in meta["packages"]}
    breaches = []
    for package in meta["packages"]:
        here = members[package["name"]]
        top = here.parts[0]
        if here == Path("host"):
            breaches.append(
                f"host/Cargo.toml: {package['name']} is the folder host/ itself: host/ holds "
                "crates only, each in a folder named for its job, so the layout says what each is"
            )
        for dep in package["dependencies"]:
            name = dep["name"]
            if top == "host" and name in members and members[name].parts[0] == "rig":
                breaches.append(
                    f"{here}/Cargo.toml: {package['name']} depends on {name} ({members[name]}): "
                    "the product's libraries must not need the virtual rig; take a trait and "
                    "let the CLI wire the rig in (as fpm-camera's TriggerPulses)"
                )
            if name == "clap" and top not in ("cli", "tools"):
                breaches.append(
                    f"{here}/Cargo.toml: {package['name']} depends on clap: parse arguments "
                    "in cli/ (or a tool under tools/) into the library's own types"
                )
    for package in meta["packages"]:
        sources = {
            Path(t["src_path"]).parent
            for t in package["targets"]
            if {"lib", "rlib", "cdylib", "bin"} & set(t["kind"])
        }
        for src in sources:
            for group in circles(src):
                breaches.append(
                    f"{src.relative_to(root)}: modules of {package['name']} import each other "
                    f"round a circle: {', '.join(sorted(group))}; move what they share into a "
                    "module of its own, or pass it in"
                )
    breaches += length_breaches(root)
    for b in breaches:
        print(b, file=sys.stderr)
    if not breaches:
        print(
            f"architecture: {len(members)} crates checked (host/ holds crates only and imports nothing from rig/; "
            "clap only in cli/ and tools/; no module circles; no function "
            f"over {MAX_FUNCTION_LINES} lines but the {len(known_long(root))} listed)"
        )
    return 1 if breaches else 0


if __name__ == "__main__":
    sys.exit(main())
