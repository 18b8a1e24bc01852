"""Numbers that people write: safe arithmetic expressions in scene files.

Any scalar of a scene may be a TOML string holding an expression such as
``"pi/2"``, ``"0.25*pi"``, ``"30 deg"``, ``"sqrt(3)/2"`` or
``"-0.1425 + 0.08"``.  Geometry that must agree to 1e-9 (contact points,
guard values, URDF-consistent poses) can then be written exactly instead of
as six rounded digits.

The expression is parsed by a small recursive-descent parser over a
whitelist grammar and computed as it is parsed; nothing is ever evaluated as
Python code::

    expr    := term (("+" | "-") term)*
    term    := unary (("*" | "/") unary)*
    unary   := ("+" | "-") unary | power
    power   := postfix ("**" unary)?          (right-associative; -2**2 = -4)
    postfix := atom "deg"*                    ("30 deg" = 30 pi / 180)
    atom    := NUMBER | "pi" | "e" | FUNC "(" expr ("," expr)* ")" | "(" expr ")"
    FUNC    := sqrt | sin | cos | tan | atan2

An error names the position (1-based character) in the expression and what
was expected there; the scene loader adds the file and the field.  Every value
met on the way (a number, a function's argument, a partial result) must be a
finite double, and nesting (parentheses, signs, powers, calls) is at most
:data:`MAX_NESTING` deep: beyond either, an error at the position at fault, never
a Python traceback.  Tokenizing and parsing take time linear in the length.
"""
from __future__ import annotations

import difflib
import math
import re

CONSTANTS = {"pi": math.pi, "e": math.e}
FUNCTIONS = {"sqrt": (math.sqrt, 1), "sin": (math.sin, 1), "cos": (math.cos, 1), "tan": (math.tan, 1),
             "atan2": (math.atan2, 2)}
DEG = math.pi / 180.0
_SPACE = re.compile(r"\s*")
_TOKEN = re.compile(r"(?:(?P<num>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)|(?P<name>[A-Za-z_]\w*)"
                    r"|(?P<op>\*\*|[-+*/(),]))")


#: Deepest nesting of parentheses, signs, powers and calls (each level is a few Python frames
#: of the recursive-descent parser; far below the interpreter's recursion limit).
MAX_NESTING = 64
#: Longest stretch of an expression quoted in a message (a long one is shown around the fault).
QUOTE = 60
MAX_DOUBLE = 1.7976931348623157e308


def excerpt(text: str, position: int = 1) -> str:
    """``text`` quoted, or for a long one the stretch around ``position`` (1-based) with its
    length, so a message about a 1 MB expression stays one line."""
    if len(text) <= QUOTE:
        return repr(text)
    lo = max(0, min(position - 1 - QUOTE // 2, len(text) - QUOTE))
    part = ("..." if lo > 0 else "") + text[lo:lo + QUOTE] + ("..." if lo + QUOTE < len(text) else "")
    return f"{part!r} ({len(text)} characters)"


class ExpressionError(ValueError):
    """A malformed or unsafe expression; ``position`` is 1-based."""

    def __init__(self, text: str, position: int, reason: str):
        self.text, self.position, self.reason = text, position, reason
        super().__init__(f"{reason} at position {position} of {excerpt(text, position)}")


def _tokens(text: str) -> list[tuple[str, str, int]]:
    """(kind, text, 1-based position) of every token, then ("end", "", len + 1); each character
    is looked at a bounded number of times (linear time)."""
    out, i, n = [], 0, len(text)
    while True:
        i = _SPACE.match(text, i).end()
        if i >= n:
            break
        m = _TOKEN.match(text, i)
        if m is None:
            raise ExpressionError(text, i + 1, f"unexpected character {text[i]!r} (allowed: numbers, "
                                  "+ - * / ** ( ), pi, e, deg, sqrt, sin, cos, tan, atan2)")
        kind = m.lastgroup
        out.append((kind, m.group(kind), i + 1))
        i = m.end()
    out.append(("end", "", n + 1))
    return out


class _Parser:
    def __init__(self, text: str):
        self.text = text
        self.toks = _tokens(text)
        self.i = 0
        self.depth = 0

    @property
    def tok(self):
        return self.toks[self.i]

    def _fail(self, reason, tok=None):
        raise ExpressionError(self.text, (tok or self.tok)[2], reason)

    def _take(self, value):
        if self.tok[1] == value and self.tok[0] != "num":
            self.i += 1
            return True
        return False

    def _finite(self, val, tok, what):
        """``val``, or an error at ``tok`` when ``what`` is not a finite double."""
        if not math.isfinite(val):
            self._fail(f"{what} is not finite ({val}; the largest double is about {MAX_DOUBLE:.3g})", tok)
        return val

    def parse(self) -> float:
        if self.tok[0] == "end":
            self._fail("empty expression")
        try:
            val = self.expr()
        except RecursionError:  # a deep caller's stack: the same message as MAX_NESTING's
            self._fail(self._too_deep())
        if self.tok[0] != "end":
            self._fail(f"unexpected {self.tok[1]!r} (an operator + - * / ** is missing?)")
        return val

    def expr(self):
        val = self.term()
        while self.tok[1] in ("+", "-") and self.tok[0] == "op":
            op, at = self.tok[1], self.tok
            self.i += 1
            rhs = self.term()
            val = self._finite(val + rhs if op == "+" else val - rhs, at, f"the result of {op!r}")
        return val

    def term(self):
        val = self.unary()
        while self.tok[1] in ("*", "/") and self.tok[0] == "op":
            op, at = self.tok[1], self.tok
            self.i += 1
            rhs = self.unary()
            if op == "/" and rhs == 0:
                self._fail("division by zero", at)
            val = self._finite(val * rhs if op == "*" else val / rhs, at, f"the result of {op!r}")
        return val

    def _too_deep(self) -> str:
        return (f"nested more than {MAX_NESTING} levels deep (parentheses, signs, powers, calls); "
                "write it with fewer levels")

    def unary(self):
        """Every level of nesting passes here (a '(' or a call through expr, a sign, a power's
        exponent), so the depth is counted here."""
        self.depth += 1
        if self.depth > MAX_NESTING:
            self._fail(self._too_deep())
        try:
            if self.tok[0] == "op" and self.tok[1] in ("+", "-"):
                sign = -1.0 if self.tok[1] == "-" else 1.0
                self.i += 1
                return sign * self.unary()
            return self.power()
        finally:
            self.depth -= 1

    def power(self):
        base = self.postfix()
        if self._take("**"):
            at = self.toks[self.i - 1]
            exponent = self.unary()
            try:
                val = base ** exponent
            except (OverflowError, ZeroDivisionError) as exc:
                self._fail(f"power out of range ({exc})", at)
            if isinstance(val, complex):
                self._fail("a negative number to a fractional power", at)
            return self._finite(val, at, "the result of '**'")
        return base

    def postfix(self):
        val = self.atom()
        while self.tok == ("name", "deg", self.tok[2]):
            self.i += 1
            val = self._finite(val * DEG, self.toks[self.i - 1], "the angle in radians")
        return val

    def atom(self):
        kind, text, pos = self.tok
        if kind == "num":
            self.i += 1
            short = text if len(text) <= 24 else f"{text[:12]}...{text[-8:]}"
            return self._finite(float(text), self.toks[self.i - 1], f"the number {short!r}")
        if kind == "op" and text == "(":
            self.i += 1
            val = self.expr()
            if not self._take(")"):
                self._fail("expected ')'")
            return val
        if kind == "name":
            self.i += 1
            if text in CONSTANTS:
                return CONSTANTS[text]
            if text in FUNCTIONS:
                return self.call(text, pos)
            known = list(CONSTANTS) + list(FUNCTIONS) + ["deg"]
            close = difflib.get_close_matches(text, known, n=1, cutoff=0.6)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            if text == "deg":
                self._fail("'deg' follows a number, as in '30 deg'", self.toks[self.i - 1])
            self._fail(f"unknown name {text!r}{hint}; allowed: {', '.join(known)}", self.toks[self.i - 1])
        if kind == "end":
            self._fail("the expression ends too early: a number, name or '(' is missing")
        self._fail(f"expected a number, a name or '(' but found {text!r}")

    def call(self, name, pos):
        fn, arity = FUNCTIONS[name]
        if not self._take("("):
            self._fail(f"{name} needs its argument in parentheses, as in '{name}(...)'")
        args = []
        while not args or self._take(","):
            args.append(self.expr())
        if not self._take(")"):
            self._fail("expected ')' or ','")
        if len(args) != arity:
            raise ExpressionError(self.text, pos, f"{name} takes {arity} argument{'s' * (arity > 1)}, "
                                  f"not {len(args)}")
        if name == "sqrt" and args[0] < 0:
            raise ExpressionError(self.text, pos, f"sqrt of a negative number ({args[0]:g})")
        if name == "atan2" and args[0] == 0 and args[1] == 0:  # math.atan2 gives 0 (or +-pi): no direction
            raise ExpressionError(self.text, pos, "atan2(0, 0): the zero vector has no angle")
        try:  # the arguments are finite; a function whose result overflows says so
            return self._finite(fn(*args), ("name", name, pos), f"{name}(...)")
        except (ValueError, OverflowError) as exc:
            raise ExpressionError(self.text, pos, f"{name} is not defined there ({exc})") from None


def evaluate(text: str) -> float:
    """The value of the expression ``text``; :class:`ExpressionError` when it is not one."""
    val = _Parser(text).parse()
    if not math.isfinite(val):
        raise ExpressionError(text, 1, f"the value is not finite ({val})")
    return float(val)


def describe(exc: ExpressionError) -> str:
    """The problem text a scene error shows (the loader prefixes the file and the field)."""
    allowed = "" if "allowed" in exc.reason else \
        " (an expression may use numbers, + - * / ** ( ), pi, e, deg, sqrt, sin, cos, tan, atan2)"
    return f"= {excerpt(exc.text, exc.position)}: at position {exc.position}: {exc.reason}{allowed}"
