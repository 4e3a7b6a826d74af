"""Plant-model framework: composable parts, diagrams, and a compiled fixed-step simulator."""

from rehab_hil.models.system import CompiledSystem, Diagram, DiagramError, Part, SimulationResult

__all__ = ["CompiledSystem", "Diagram", "DiagramError", "Part", "SimulationResult"]
