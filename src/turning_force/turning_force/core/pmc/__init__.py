"""The PMC side: what reaches the CNC's feedrate override. The override tables (:mod:`.overrides`)
and how a machine is wired (:mod:`.machine`), the gate that keeps the machine safe first
(settings :mod:`.settings`, compiled :mod:`.gate`) with the shop floor's behaviours
(:mod:`.shopfloor`)."""
