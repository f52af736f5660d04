#!/usr/bin/env python3
"""Checks of the workspace's shape that a reviewer would otherwise have to remember
(docs/architecture.md): run by .ci/run, and by hand with `python3 tools/ci/architecture.py`.

- Nothing under host/ (the product's libraries) depends on a crate under rig/ (the
  virtual rig, which stands in for hardware): the product must not need its stand-in.
- clap (argument parsing) is a dependency of the command-line crates only (cli/,
  tools/): libraries take typed options, and the CLI parses into them.

Reads `cargo metadata`, so the dependencies are the ones cargo resolves, whatever the
manifests' spelling. Exits 1 listing every breach.
"""

import json
import subprocess
import sys
from pathlib import Path


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
    for b in breaches:
        print(b, file=sys.stderr)
    if not breaches:
        print(f"architecture: {len(members)} crates checked (host/ imports nothing from rig/; clap only in cli/ and tools/)")
    return 1 if breaches else 0


if __name__ == "__main__":
    sys.exit(main())
