#!/usr/bin/python3
"""Fails when a function in src/ is longer than the limit (lines from its signature to its
closing brace; lambdas count with the function that holds them) or a tool's main longer than
the tools' limit. Usage: check_function_length.py SOURCE_DIR [--limit 120] [--main-limit 100]"""
import argparse
import pathlib
import re
import sys


def functions(text):
    """(first line, line count, signature) of every top-level function body."""
    lines = text.split("\n")
    stack = []  # kinds of the open braces: 'fn' with its start line, or 'other'
    for i, line in enumerate(lines):
        code = re.sub(r'"(\\.|[^"\\])*"', '""', line)
        code = re.sub(r"'(\\.|[^'\\])'", "''", code).split("//")[0]
        for ch in code:
            if ch == "{":
                in_function = any(kind == "fn" for kind, _ in stack)
                scope = re.match(r"^\s*(namespace|extern|struct|class|enum|union)\b", line)
                if in_function or (scope and not line.rstrip().endswith(");")):
                    stack.append(("other", i))
                    continue
                start = i  # the signature may span lines above the brace
                while (start > 0 and lines[start - 1].strip() and
                       not lines[start - 1].rstrip().endswith((";", "}", "{")) and
                       not lines[start - 1].strip().startswith(("//", "#"))):
                    start -= 1
                stack.append(("fn", start))
            elif ch == "}" and stack:
                kind, start = stack.pop()
                if kind == "fn":
                    yield start + 1, i - start + 1, lines[start].strip()


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("source_dir")
    parser.add_argument("--limit", type=int, default=120)
    parser.add_argument("--main-limit", type=int, default=100)
    args = parser.parse_args()
    root = pathlib.Path(args.source_dir)
    failures = []
    for path in sorted((root / "src").rglob("*.cpp")):
        for line, length, signature in functions(path.read_text()):
            is_main = signature.startswith("int main(")
            limit = args.main_limit if is_main else args.limit
            if length > limit:
                failures.append(f"{path.relative_to(root)}:{line}: {length} lines "
                                f"(limit {limit}): {signature[:80]}")
    for f in failures:
        print(f)
    print(f"{len(failures)} functions over the limit")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
