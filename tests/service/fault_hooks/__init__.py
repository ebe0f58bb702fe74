"""Test-only fault injection for real worker processes: a worker launcher that installs the
faults its environment asks for (``worker``), a pausable TCP proxy (``proxy``), the processes
of one deployment (``cluster``) and the fault scenarios the test suite and ``bench/faults.py``
share (``scenarios``). Nothing here is imported by production code."""
