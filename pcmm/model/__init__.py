"""A configuration as a mechanism: its Pinocchio model, force elements, coordinates (a tree, or
loops and drives by coordinate partitioning, behind the ``Coordinates`` protocol), the optional
compiled evaluations, the closed-loop assembly and the mechanism of all configurations."""
