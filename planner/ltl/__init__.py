"""LTL formulas to Büchi automata: parsing, rewriting, translation (Gastin-Oddoux), reduction,
pruning and direct semantics on lassos."""
