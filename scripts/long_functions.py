#!/usr/bin/env python3
"""Lists C++ functions longer than a limit (default 80 lines), longest first.

A function is a definition that starts at namespace level (any indentation
inside a class body included) with a line ending in '{' that is not a
namespace, class, struct, enum or union, and ends at its matching brace.
Lambdas count towards the function that holds them. Comments and string
literals are stripped before braces are matched.

Usage: scripts/long_functions.py [--limit N] [PATH ...]   (default: src/)
Exits 1 when any function is over the limit (for CI-style checks).
"""
import argparse
import pathlib
import re
import sys

KEYWORDS = re.compile(r"^\s*(namespace|class|struct|enum|union|extern)\b")


def strip(text):
    text = re.sub(r"/\*.*?\*/", lambda m: "\n" * m.group(0).count("\n"), text, flags=re.S)
    text = re.sub(r"//[^\n]*", "", text)
    text = re.sub(r'R"\((.*?)\)"', lambda m: '""' + "\n" * m.group(0).count("\n"), text, flags=re.S)
    text = re.sub(r'"(\\.|[^"\\\n])*"', '""', text)
    text = re.sub(r"'(\\.|[^'\\\n])*'", "''", text)
    return text


def functions(path):
    text = strip(path.read_text(errors="replace"))
    scopes = []  # stack of (kind, start line, name)
    head = []  # characters of the declaration being read at namespace/class level
    number = 1
    for char in text:
        in_function = any(kind == "function" for kind, _, _ in scopes)
        if char == "\n":
            number += 1
        if char == "{":
            declaration = " ".join("".join(head).split())
            before_paren = declaration.split("(")[0]
            if (in_function or "(" not in declaration or KEYWORDS.match(declaration)
                    or "=" in before_paren or before_paren.strip().endswith(("if", "for", "while", "switch"))):
                scopes.append(("block", number, declaration))
            else:
                words = before_paren.split()
                scopes.append(("function", number, words[-1] if words else declaration))
            head = []
        elif char == "}":
            if scopes:
                kind, start, name = scopes.pop()
                if kind == "function":
                    yield name, start, number - start + 1
            head = []
        elif char in ";:" and not in_function:
            # A statement or an access specifier ends; keep '::' of qualified names.
            if char == ";" or (head and head[-1] != ":"):
                pass
            if char == ";":
                head = []
            else:
                head.append(char)
        elif not in_function:
            head.append(char)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--limit", type=int, default=80)
    parser.add_argument("paths", nargs="*", default=["src"])
    args = parser.parse_args()
    found = []
    for root in args.paths:
        root = pathlib.Path(root)
        files = [root] if root.is_file() else sorted(root.rglob("*.[ch]*"))
        for path in files:
            if path.suffix not in (".cc", ".cpp", ".h", ".hpp"):
                continue
            for name, start, length in functions(path):
                if length > args.limit:
                    found.append((length, f"{path}:{start}", name))
    for length, where, name in sorted(found, reverse=True):
        print(f"{length:5d}  {where}  {name}")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
