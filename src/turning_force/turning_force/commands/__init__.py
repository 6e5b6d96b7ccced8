"""The commands of ``turning-force`` that run things: the graph on the simulator (:mod:`.run`), a
session played into a live graph (:mod:`.play`), the core loop recorded (:mod:`.core_session`),
sweeps (:mod:`.sweep`), the papers' figures (:mod:`.papers`) and the robustness matrix
(:mod:`.robustness`). Above the nodes and the session storage, below the command line."""
