"""Our control laws, one module each (:mod:`turning_force.core.control.law` says what a law's
module holds). Every module here is a law: adding one is adding its module (and its test);
another package adds one through the ``turning_force.laws`` entry point group
(docs/writing-a-law.md)."""
