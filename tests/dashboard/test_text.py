"""``baarda.dashboard.text``: titles broken into lines that fit their plot (Bokeh cuts a title
that runs beyond the canvas; the browser check is ``tests/browser/test_layout.py``)."""

from __future__ import annotations

from hypothesis import given, strategies as st

from baarda.dashboard.text import TITLE_EM, fit_title, id_list

WORDS = st.lists(st.text(alphabet="abcdefghijklmnopqrstuvwxyz×σ0δ̄∇()[]=.,:", min_size=1, max_size=12),
                 min_size=1, max_size=20)


@given(WORDS, st.integers(150, 900), st.sampled_from([12.0, 12.7, 13.0, 14.0]))
def test_lines_fit_and_keep_every_word(words, width, font):
    text = " ".join(words)
    out = fit_title(text, width, font)
    per_line = max(int(width / (TITLE_EM * font)), 12)
    assert all(len(line) <= per_line for line in out.split("\n"))
    assert out.replace("\n", " ") == text or "".join(out.split()) == "".join(text.split())


def test_short_title_is_unchanged_and_a_long_one_breaks_at_a_space():
    assert fit_title("Layout: 60 points, 448 observations", 420) == "Layout: 60 points, 448 observations"
    long = "Standard ellipses ×5000, largest drawn 131 mm (σ0 a priori, own datum)"
    out = fit_title(long, 420)
    assert out.count("\n") == 1 and out.replace("\n", " ") == long


@given(st.lists(st.text(min_size=1, max_size=12), max_size=40), st.integers(1, 10))
def test_id_list_names_at_most_most_ids_and_counts_the_rest(ids, most):
    said = id_list(ids, most)
    assert "\n" not in said and "\x1b" not in said
    if len(ids) <= most:
        assert " more" not in said or any("more" in i for i in ids)
    else:
        assert said.endswith(f" and {len(ids) - most:,} more")


def test_id_list_of_a_large_datum():
    assert id_list([str(k) for k in range(7776)]) == "0, 1, 2, 3, 4, 5, 6, 7 and 7,768 more"
    assert id_list(["A", "B"]) == "A, B"
