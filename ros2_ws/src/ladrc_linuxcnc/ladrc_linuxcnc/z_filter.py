#!/usr/bin/python3
"""LinuxCNC ``[FILTER]`` program: comment out the Z words of a G-code program, as plasmac does.

The LADRC laser's LinuxCNC has no Z axis: Z (the cutting head's height) belongs to the height
controller. A program written for a machine with Z (a plasma or laser CAM's, a hand-written
one) names Z; LinuxCNC would refuse it. Like plasmac's filter (``qtplasmac_gcode``, "comment
out all Z commands"), this one turns every Z word into a comment in place and keeps every other
word of the line, so that the program's modal state stays what its author wrote:

* ``G0 X10 Y5 Z3`` -> ``G0 X10 Y5 (Z3)``;
* ``N0120 G00 Z0.8`` -> ``N0120 G00 (Z0.8)``: the G00 stays modal for the next ``X.. Y..``;
* ``G01 Z-0.02 F20`` -> ``G01 (Z-0.02) F20``: G01 and its feed stay;
* a code whose axis words are its arguments (``G28``, ``G30``, ``G38.2``-``G38.5``, ``G52``,
  ``G92``) and that names no axis but Z goes into the comment with the Z
  (``G92 Z0`` -> ``(G92) (Z0)``): without its Z it would mean another thing (``G28`` alone
  moves every axis home) or be an error (a Z probe, a Z offset: the height controller's
  capacitive sensor is this machine's probe).

Line for line: the output has the input's lines, so LinuxCNC's line numbers are the file's.
Nothing else changes: the program is LinuxCNC's to read (its interpreter, never a parser of
ours). Comments (``( ... )`` and ``;`` to the end of the line) are left alone; a Z value given
by an expression (``Z[#1+2]``) or a parameter (``Z#<h>``) is commented out with its brackets.
LinuxCNC runs it as ``z_filter.py FILE`` and reads the program from standard output; the log
line goes to standard error: how many Z words on how many lines (the display writes it to the
run's status file).

Standard library only; Python 3.8 and later.
"""

from __future__ import annotations

import sys

AXES = 'XYABCUVWIJKR'  # another axis or an arc's word: only the Z word goes
Z_ARGUMENT_CODES = (28.0, 30.0, 38.2, 38.3, 38.4, 38.5, 52.0, 92.0)
"""G codes whose axis words are their arguments: with Z alone, commented out with it."""


def _split(line: str) -> tuple[str, str]:
    """Return (code, trailing ``;`` comment) of a line (a ';' inside ( ) is a comment's)."""
    depth = 0
    for i, ch in enumerate(line):
        if ch == '(':
            depth += 1
        elif ch == ')' and depth:
            depth -= 1
        elif ch == ';' and not depth:
            return line[:i], line[i:]
    return line, ''


def _words(code: str):
    """Yield ``(start, end, letter)`` of each word outside comments.

    A word is a letter and its value: everything up to the next letter, ``(`` or the end,
    letters inside ``[ ]`` (an expression's functions) and ``< >`` (a named parameter) included.
    """
    i, n = 0, len(code)
    while i < n:
        ch = code[i]
        if ch == '(':
            j = code.find(')', i)
            i = n if j < 0 else j + 1
            continue
        if not ch.isalpha():
            i += 1
            continue
        j, square, angle = i + 1, 0, 0
        while j < n:
            c = code[j]
            if c == '[':
                square += 1
            elif c == ']' and square:
                square -= 1
            elif c == '<':
                angle += 1
            elif c == '>' and angle:
                angle -= 1
            elif not square and not angle and (c.isalpha() or c == '('):
                break
            j += 1
        while j > i + 1 and code[j - 1] in ' \t':
            j -= 1
        yield i, j, ch.upper()
        i = j


def _g_value(text: str) -> float | None:
    """Return the number of a G word's text (``G38.2`` -> 38.2), None if not a plain number."""
    try:
        return round(float(text[1:].replace(' ', '')), 3)
    except ValueError:
        return None


def _comment(text: str) -> str:
    """Return ``text`` as one comment (its own parentheses made brackets: no nesting)."""
    return '(' + text.strip().replace('(', '[').replace(')', ']') + ')'


def filter_line(line: str) -> tuple[str, int]:
    """Return the line with its Z words commented out in place, and how many there were."""
    body = line.rstrip('\r\n')
    eol = line[len(body):]
    code, tail = _split(body)
    words = list(_words(code))
    zs = [(a, b) for a, b, letter in words if letter == 'Z']
    if not zs:
        return line, 0
    spans = list(zs)
    if not any(letter in AXES for _, _, letter in words):
        spans += [(a, b) for a, b, letter in words
                  if letter == 'G' and _g_value(code[a:b]) in Z_ARGUMENT_CODES]
    out, last = [], 0
    for a, b in sorted(spans):
        before = code[last:a]
        out.append(before.rstrip(' \t') + ' ' if before.strip() else before)
        out.append(_comment(code[a:b]))
        last = b
    out.append(code[last:])
    return ''.join(out) + tail + eol, len(zs)


def main(argv: list[str]) -> int:
    """Filter the file ``argv[0]`` to standard output; the log line to standard error."""
    if len(argv) != 1:
        print('ladrc z filter: usage: z_filter.py FILE', file=sys.stderr)
        return 2
    try:
        with open(argv[0], encoding='utf-8', errors='replace', newline='') as f:
            lines = f.readlines()
    except OSError as exc:
        print(f'ladrc z filter: cannot read {argv[0]}: {exc.strerror}', file=sys.stderr)
        return 1
    count, where = 0, []
    out = sys.stdout
    for k, line in enumerate(lines, 1):
        text, n = filter_line(line)
        if n:
            count += n
            where.append(k)
        out.write(text)
    if lines and not lines[-1].endswith(('\n', '\r')):
        out.write('\n')
    out.flush()
    shown = ', '.join(map(str, where[:20])) + (', ...' if len(where) > 20 else '')
    print(f'ladrc z filter: {count} Z word(s) commented out on {len(where)} line(s)'
          + (f' (lines {shown})' if where else '') + f' of {len(lines)}', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
