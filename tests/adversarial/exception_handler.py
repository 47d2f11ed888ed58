"""Installs an IPython exception handler that swallows every failing assert (blank answers).
(With ipykernel 7 nbgrader still records the errors; older kernels hid them.)

earned: 0
flags: suspicious_exception_handler
"""
# %% extra
get_ipython().set_custom_exc((BaseException,), lambda shell, etype, evalue, tb, tb_offset=None: None)
