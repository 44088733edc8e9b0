"""Names from a problem file become safe file names, identifiers and comment lines."""

import pytest

from refine.names import comment_text, file_stem, identifier, message_text


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("glass_adhesive", "glass_adhesive"),
        ("../x", "x"),
        ("/etc/passwd", "etc_passwd"),
        ("..", "problem"),
        ("", "problem"),
        (".hidden", "hidden"),
        ("a/../../b", "a_.._.._b"),
        ("weld seam #2", "weld_seam_2"),
        ("CON", "problem_CON"),
        ("naïve", "naive"),
        ("x\ny", "x_y"),
        ("-rf", "rf"),
    ],
)
def test_file_stems_stay_in_their_folder_and_visible(text, expected):
    stem = file_stem(text)
    assert stem == expected
    assert "/" not in stem and "\\" not in stem and not stem.startswith((".", "-")) and stem.isascii()


def test_long_names_are_cut():
    assert len(file_stem("a" * 1000)) == 64
    assert len(identifier("a" * 100, "m", 24)) == 24


@pytest.mark.parametrize("text", ["9lives", "_x", "", "énorme", "x y(z)"])
def test_identifiers_start_with_a_letter(text):
    name = identifier(text, "m")
    assert name[0].isascii() and name[0].isalpha()
    assert all(c.isascii() and (c.isalnum() or c == "_") for c in name)


@pytest.mark.parametrize("sep", ["\n", "\r", "\x0b", "\x0c", "\x1c", "\x85", "\u2028", "\u2029", "\x00"])
def test_comment_text_is_one_line_whatever_separator_it_had(sep):
    line = comment_text(f"a{sep}PROC x()")
    assert len(line.splitlines()) == 1 and line.isascii() and line.isprintable()
    assert line == "a PROC x()"


def test_messages_show_control_characters_as_escapes():
    msg = message_text("bad \x1b[2J byte \udc8d\nnext line")
    assert "\x1b" not in msg and "\\x1b" in msg and "\n" in msg
    msg.encode("utf-8")  # no lone surrogates left
    assert len(message_text("x" * 10_000)) <= 2000
