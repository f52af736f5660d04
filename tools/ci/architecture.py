#!/usr/bin/env python3
"""Checks of the workspace's shape that a reviewer would otherwise have to remember
(docs/architecture.md): run by .ci/run, and by hand with `python3 tools/ci/architecture.py`.

- Nothing under host/ (the product's libraries) depends on a crate under rig/ (the
  virtual rig, which stands in for hardware): the product must not need its stand-in.
- clap (argument parsing) is a dependency of the command-line crates only (cli/,
  tools/): libraries take typed options, and the CLI parses into them.
- No two modules of a crate import each other, directly or round a circle (each file
  a module; its `crate::`, `super::` and `self::` paths outside comments and test
  modules are its imports). The one circle left is listed in KNOWN_CIRCLES with the
  issue that removes it; a new one fails.

Reads `cargo metadata`, so the dependencies are the ones cargo resolves, whatever the
manifests' spelling. Exits 1 listing every breach.
"""

import json
import re
import subprocess
import sys
from pathlib import Path

# Circles being taken apart, by crate: remove an entry when its circle is gone.
KNOWN_CIRCLES = {
    # Issue 62: every acquisition mode one machine (the modes' drivers import each
    # other through MAX_MULTIPLEX, Control/Watcher and ScanStage).
    "fpm-acquire": {"acquisition", "multiplexed", "pipeline", "scan", "stage"},
}


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
                if group == KNOWN_CIRCLES.get(package["name"]):
                    continue
                breaches.append(
                    f"{src.relative_to(root)}: modules of {package['name']} import each other "
                    f"round a circle: {', '.join(sorted(group))}; move what they share into a "
                    "module of its own, or pass it in"
                )
    for b in breaches:
        print(b, file=sys.stderr)
    if not breaches:
        print(
            f"architecture: {len(members)} crates checked (host/ imports nothing from rig/; "
            "clap only in cli/ and tools/; no module circles but the known one)"
        )
    return 1 if breaches else 0


if __name__ == "__main__":
    sys.exit(main())
