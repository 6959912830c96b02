#!/usr/bin/python3
"""LinuxCNC ``[FILTER]`` program: comment out the Z words of a G-code program, as plasmac does.

The LADRC laser's LinuxCNC has no Z axis: Z (the cutting head's height) belongs to the height
controller. A program written for a machine with Z (a plasma or laser CAM's, a hand-written
one) names Z; LinuxCNC would refuse it. Like plasmac's filter (``qtplasmac_gcode``, "comment
out all Z commands"), this one makes every Z word a comment before LinuxCNC reads the program:

* a line with Z and another axis or arc word (X, Y, I, J, R, ...): the Z word and its value
  become a comment,
  ``G0 X10 Y5 Z3`` -> ``G0 X10 Y5 (Z3)``;
* a line whose only axis word is Z: the whole line becomes a comment, ``G0 Z5`` -> ``(G0 Z5)``.

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


def filter_line(line: str) -> tuple[str, int]:
    """Return the line with its Z words commented out, and how many there were."""
    body = line.rstrip('\r\n')
    eol = line[len(body):]
    code, tail = _split(body)
    words = list(_words(code))
    zs = [(a, b) for a, b, letter in words if letter == 'Z']
    if not zs:
        return line, 0
    if not any(letter in AXES for _, _, letter in words):
        inner = code.strip().replace('(', '[').replace(')', ']')
        return f'({inner}){tail}{eol}', len(zs)
    out, last = [], 0
    for a, b in zs:
        out.append(code[last:a].rstrip(' \t') + ' ')
        out.append('(' + code[a:b].strip().replace('(', '[').replace(')', ']') + ')')
        last = b
    out.append(code[last:])
    return ''.join(out).lstrip(' ') + tail + eol, len(zs)


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
