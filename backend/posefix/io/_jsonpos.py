"""Parse JSON remembering where each object starts, to name lines in error messages.

Only used on the error path (or for small files): it runs the pure-Python decoder.
"""

from __future__ import annotations

import json
import json.decoder
import json.scanner


class PosDict(dict):
    """A dict that knows the 1-based line where its ``{`` was."""

    line: int | None = None


def loads_with_lines(text: str):
    """``json.loads`` whose objects are ``PosDict`` with ``.line`` set."""
    newline_pos: list[int] = [i for i, ch in enumerate(text) if ch == "\n"]

    def line_at(pos: int) -> int:
        import bisect

        return bisect.bisect_right(newline_pos, pos) + 1

    decoder = json.JSONDecoder()

    def parse_object(s_and_end, strict, scan_once, object_hook, object_pairs_hook, memo=None, _w=None):
        s, end = s_and_end
        obj, new_end = json.decoder.JSONObject(s_and_end, strict, scan_once, None, None, memo if memo is not None else {})
        out = PosDict(obj)
        out.line = line_at(end - 1)
        return out, new_end

    decoder.parse_object = parse_object
    decoder.scan_once = json.scanner.py_make_scanner(decoder)
    return decoder.decode(text)


def line_of_json_error(exc: json.JSONDecodeError) -> int:
    return exc.lineno
