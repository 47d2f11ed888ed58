"""The Content-Security-Policy of a page cobotlab writes itself, for wherever it is opened.

A student's feedback page (:mod:`autograder.feedback`), the class report
(:mod:`cobotlab.class_report`) and the demo's report (:mod:`cobotlab.report`) hold text from
submissions, escaped as they are written; the policy is the second line of defence, in the
page's own ``<head>`` (a file opened from disk or from a Jupyter server has no header of
ours): no script runs, whatever the page holds; its own ``<style>`` applies and its images
(files beside it, or embedded) load. No imports: the student package's demo uses it too.
"""

__all__ = ["PAGE_POLICY", "POLICY_META"]

PAGE_POLICY = ("default-src 'none'; style-src 'unsafe-inline'; img-src 'self' data:; "
               "base-uri 'none'; form-action 'none'")
POLICY_META = f'<meta http-equiv="Content-Security-Policy" content="{PAGE_POLICY}">'
