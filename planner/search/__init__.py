"""Sampling-based search: geometric RRT*, TL-RRT* over the product of the workspace and a Büchi
automaton (its trees, biased sampling, anytime shortcuts), reachability proofs, and the
planner's options."""
