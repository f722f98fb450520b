"""Lifelong execution: a warehouse shift of tasks, the live ADG, errands and the shift
executor that plans windows as it goes."""
