"""The students' reports after grading: points, what went wrong, and nothing of the hidden checks.

nbgrader's own feedback is the autograded notebook, hidden tests included, so a student who gets it back sees
them and can pass them on (jupyter/nbgrader issues 917 and 1363). :func:`write_reports` writes instead one
Markdown page per student and chapter, ``out/feedback/STUDENT/CHAPTER.md``, made of

* the points of each exercise;
* the errors the student's notebook showed in that exercise's cells (the answer, the visible tests): the
  student saw them already, and they name only what the student's code and the visible asserts said;
* the trusted checks that failed, in the checks' own words (:mod:`vdtutorial.course.checks`: which case, what is
  wrong, never the expected value), and why the grader refused an answer (:mod:`vdtutorial.course.answer_rules`).

No hidden test's code is read to write it: the hidden checks live in the grading process, and the page is built
from their verdicts alone.

Not taught in a chapter: part of the teacher's grading (vdtutorial/course/classroom.py, notebooks/TEACHING.md).
"""

from __future__ import annotations

import re
from pathlib import Path

from vdtutorial.course.checks import NO_ANSWER

#: The longest error message quoted from the student's notebook (characters).
MESSAGE_CHARS = 300
#: Characters that Markdown reads as syntax (emphasis, code, links, images, headings, tables, strikethrough).
_MARKDOWN = re.compile(r"([\\`*_\[\]#|~!{}])")


def as_text(note: str) -> str:
    """``note`` as literal text on a Markdown page: one line, HTML's ``& < >`` as entities (no tag, no script)
    and Markdown's syntax characters escaped, so that what a student's code printed or raised shows as written
    instead of becoming markup."""
    note = " ".join(note.splitlines())
    note = note.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
    return _MARKDOWN.sub(r"\\\1", note)


#: How numpy.testing's comparisons begin their message, before the test's ``err_msg`` (``Not equal to tolerance
#: rtol=...``, ``Arrays are not equal``, ...), and how the lines that follow the ``err_msg`` (the numbers) begin.
_NUMPY_HEADER = ("Not equal to tolerance", "Arrays are not")
_NUMPY_DETAILS = (
    "Mismatched elements",
    "Mismatch at index",
    "Max absolute difference",
    "Max relative difference",
    "x:",
    "y:",
    "ACTUAL:",
    "DESIRED:",
    "(shapes",
    "(mismatch",
)


def error_message(evalue: str) -> str:
    """The words of an error's message: its first non-blank line, or for a ``numpy.testing`` comparison (whose
    message starts with a blank line and a line of tolerances) the test's own ``err_msg``, which says what was
    compared, followed by the tolerances in brackets."""
    lines = [line.strip() for line in evalue.splitlines() if line.strip()]
    if not lines:
        return ""
    if not lines[0].startswith(_NUMPY_HEADER):
        return lines[0]
    said = []
    for line in lines[1:]:
        if line.startswith(_NUMPY_DETAILS):
            break
        said.append(line)
    return f"{' '.join(said)} ({lines[0]})" if said else lines[0]


def notebook_errors(autograded: Path | None) -> dict[str, list[str]]:
    """Per exercise, the errors its answer and visible-tests cells showed when the submission ran: ``Type: the
    message's words`` (:func:`error_message`); not a visible test's call of a library piece that the grading
    kernel has as a stub (:mod:`vdtutorial.course.stubs`), which the student's own run never showed."""
    import nbformat

    from vdtutorial.course import stubs

    if autograded is None or not autograded.is_file():
        return {}
    found: dict[str, list[str]] = {}
    for cell in nbformat.read(autograded, as_version=4).cells:
        grade_id = cell.metadata.get("nbgrader", {}).get("grade_id", "")
        if cell.cell_type != "code" or not grade_id:
            continue
        for output in cell.get("outputs", []):
            if output.get("output_type") == "error":
                if grade_id.endswith("_tests") and stubs.called(str(output.get("evalue", ""))):
                    continue  # the visible tests met a library piece the grading kernel has as a stub: not news
                message = error_message(str(output.get("evalue", "")))[:MESSAGE_CHARS]
                where = "the visible tests" if grade_id.endswith("_tests") else "your answer cell"
                found.setdefault(grade_id.removesuffix("_tests"), []).append(
                    f"{where} raised {output.get('ename', 'an error')}" + (f": {message}" if message else "")
                )
    return found


def report(student: str, chapter: str, scores: list, errors: dict[str, list[str]]) -> str:
    """The Markdown page of one student's chapter; ``scores`` are its :class:`~vdtutorial.course.classroom.Score`
    rows."""
    total, possible = sum(s.score for s in scores), sum(s.max_score for s in scores)
    lines = [
        f"# {chapter}: feedback for {student}",
        "",
        f"Points: {total:g} of {possible:g}.",
        "",
        "| exercise | points |",
        "|---|---|",
    ]
    lines += [f"| {s.exercise.removesuffix('_tests')} | {s.score:g} of {s.max_score:g} |" for s in scores]
    for s in scores:
        exercise = s.exercise.removesuffix("_tests")
        notes = list(errors.get(exercise, []))
        if s.refused:
            notes.append(f"the grader refused this answer: {s.refused}")
        elif s.score < s.max_score:  # an error shown above already says why the hidden check got no answer
            notes += [
                f"hidden check failed: {failure}"
                for failure in s.failed
                if not (failure == NO_ANSWER and errors.get(exercise))
            ]
        if notes:
            lines += ["", f"## {exercise}", ""] + [f"- {as_text(note)}" for note in notes]
    return "\n".join(lines) + "\n"


def write_reports(scores: list, out: Path, assignment: str) -> list[Path]:
    """One page per student and chapter under ``out/feedback/`` (``out``: the course folder of ``classroom grade``,
    whose ``autograded/`` notebooks of ``assignment`` supply the errors the student saw); returns their paths."""
    written = []
    for student, chapter in sorted({(s.student, s.chapter) for s in scores}):
        rows = [s for s in scores if (s.student, s.chapter) == (student, chapter)]
        errors = notebook_errors(out / "autograded" / student / assignment / f"{chapter}.ipynb")
        path = out / "feedback" / student / f"{chapter}.md"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(report(student, chapter, rows, errors))
        written.append(path)
    return written
