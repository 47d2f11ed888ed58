"""Patches the kernel so that no later cell really runs, yet every cell reports success
(plain nbgrader gives this blank notebook full marks).

earned: 0
flags: nbgrader_passed_but_grader_failed, suspicious_kernel_patch
"""
# %% extra
kernel = get_ipython().kernel
async def do_nothing(*args, **kwargs):
    return {"status": "ok", "execution_count": 1, "payload": [], "user_expressions": {}}
kernel.do_execute = do_nothing
