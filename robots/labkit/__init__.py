"""The labs' plumbing: capture loops, view plans and figures the notebooks call by name.

One module per lab (``lab1``, ``lab3``, ``lab4``, ``lab5``), so a notebook cell shows one idea and the
loops and plot styling around it live here. Nothing here is graded: where a helper needs a
student's function (``piece_position``, ``ibvs_velocity``) it takes it as an argument, so the
helpers never hold an answer. Poses follow the course's ``a_T_b`` names, in metres.
"""
