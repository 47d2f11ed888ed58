"""Real-robot drivers, one module per robot, found by ``robots.connect(kind, ...)``.

This package imports nothing on purpose: each driver imports its vendor SDK inside the
function that needs it, so ``import robots`` works on a laptop without any SDK installed.
"""
