"""Training, evaluation, the closed-loop comparison and the ``fourwis`` command line."""
