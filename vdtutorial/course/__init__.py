"""The course around the method: what turns the library into chapters a class can take.

Modules, one idea each: :mod:`~vdtutorial.course.viz` (meshcat scenes and matplotlib pictures in a
chapter), :mod:`~vdtutorial.course.install_check` (which pybullet and front end this machine has),
:mod:`~vdtutorial.course.chapters` (the chapters and their data written into a learner's folder),
:mod:`~vdtutorial.course.html_book` with :mod:`~vdtutorial.course.offline_assets` (the chapters as a
book that reads offline), :mod:`~vdtutorial.course.classroom` (the student edition and autograding with
nbgrader) and :mod:`~vdtutorial.course.sandbox` (the limits each graded kernel runs under).

Nothing in the library imports from here: the method in ``vdtutorial/`` runs without the course.

Taught in chapter 00.
"""
