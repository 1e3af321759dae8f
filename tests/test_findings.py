"""The findings say only what their tests show: every bullet of README.md's "What they say" and docs/RESULTS.md's
"Findings" names the claim rows it rests on ("Rows: C8 fails, ...") or the measurement behind it ("Measured:
..."), and every verdict word it gives a row is that row's verdict in docs/RESULTS.md's claims tables."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WORDS = {"holds": "holds", "ahead": "holds", "fails": "fails", "behind": "fails", "equivalent": "equivalent",
         "undecided": "undecided", "interim": "interim"}  # a bullet's word -> the table's verdict it asserts


def table_verdicts(results: str) -> dict:
    """{claim id: verdict} from the claims block: "C8" -> "fails", "P2" -> "interim" (of "interim, n = 1 of 5")."""
    block = results.split("<!-- table3.py claims -->")[1].split("<!-- /table3.py -->")[0]
    verdicts = {}
    for line in block.splitlines():
        if re.match(r"\| [CP]\d+ \|", line):
            cells = [c.strip() for c in line.strip("|").split("|")]
            verdicts[cells[0]] = next(re.match(r"\*\*(\w+)", c)[1] for c in cells if c.startswith("**"))
    return verdicts


def bullets(text: str, start: str, end: str) -> list[str]:
    """The top-level bullets between two headings (or lines), each joined into one line."""
    part = text.split(start, 1)[1].split(end, 1)[0]
    return [" ".join(b.split()) for b in re.findall(r"^- (.*?)(?=^- |\Z)", part, re.M | re.S)]


def check(found: list[str], verdicts: dict) -> list[str]:
    """What is wrong with these bullets: no Rows:/Measured:, an unknown row, a word other than the table's."""
    wrong = []
    for bullet in found:
        if "Rows:" not in bullet and "Measured:" not in bullet:
            wrong.append(f"names neither its rows nor its measurement: {bullet[:80]}")
        for rows in re.findall(r"Rows: ([^.]*)", bullet):
            for row, word in re.findall(r"\b([CP]\d+) (\w+)", rows):
                if row not in verdicts:
                    wrong.append(f"{row}: no such claim row")
                elif WORDS.get(word) != verdicts[row]:
                    wrong.append(f"{row} {word}: the table says {verdicts[row]}")
    return wrong


def test_every_finding_names_its_rows_and_agrees_with_their_verdicts():
    results = (ROOT / "docs" / "RESULTS.md").read_text()
    verdicts = table_verdicts(results)
    assert len([k for k in verdicts if k.startswith("C")]) == 18 and len([k for k in verdicts if k[0] == "P"]) == 8
    found = bullets(results, "## Findings", "\n## ") + bullets((ROOT / "README.md").read_text(), "What they say",
                                                                "\n## ")
    assert len(found) >= 10
    assert check(found, verdicts) == []


def test_a_finding_that_misstates_a_verdict_or_names_no_row_is_caught():
    verdicts = {"C8": "fails", "C7": "undecided", "P2": "interim"}
    assert check(["**x.** Rows: C8 fails, C7 undecided, P2 interim."], verdicts) == []
    assert check(["**x.** Rows: C8 behind."], verdicts) == []  # behind: the claim fails
    assert check(["**x.** Rows: C7 fails."], verdicts) == ["C7 fails: the table says undecided"]
    assert check(["**x.** Rows: C99 holds."], verdicts) == ["C99: no such claim row"]
    assert check(["**TARL comes second.**"], verdicts)[0].startswith("names neither its rows nor its measurement")
