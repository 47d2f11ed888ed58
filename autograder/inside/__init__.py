"""What runs inside the grading sandbox, next to student code: the worker that runs a
notebook's cells and calls its functions (:mod:`.worker`), the namespaces and keyring filter
a template's forks enter (:mod:`.isolate`, :mod:`.syscalls`), the message format on its pipes
(:mod:`.wire`), the stand-ins for other graded functions (:mod:`.standin`) and the run-time
nets against forbidden routines (:mod:`.tripwire`).

The worker's view (:func:`autograder.views.worker_view`) binds this package whole. It
imports nothing of the trusted grader, the specs or the answers (only the standard library,
numpy and itself: ``tests/test_trust_zones.py`` walks its imports), so nothing the sandbox
can read holds a truth, a tolerance or the secret. What it sends back is decoded and
validated on the trusted side.
"""
