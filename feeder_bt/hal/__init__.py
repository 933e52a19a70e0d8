"""Hardware abstraction layer: one interface per sub-system (``interfaces``), one package
per implementation (``sim``, ``mock``; real drivers later). Trees see only the interfaces."""
