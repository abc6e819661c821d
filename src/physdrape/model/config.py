"""Model configuration: a frozen dataclass, loaded strictly from YAML/JSON mappings."""

from __future__ import annotations

import enum
from dataclasses import dataclass

from physdrape.model.stretching_solver import SolverKind
from physdrape.physics.contact import DEFAULT_MARGIN, DEFAULT_STIFFNESS


class Variant(str, enum.Enum):
    """Which modules run (the paper's ablations are switches of one model)."""

    GNN_ONLY = "gnn"  # X = X_init + Δx
    GNN_SOLVER = "gnn+solver"  # + stretching solver
    GNN_COLLISION = "gnn+collision"  # + collision handler, no solver
    FULL = "full"  # GNN → solver → handler (PhysDrape)
    POST_COL = "post-col"  # trained as GNN+solver; handler with δ = 1 applied only at inference

    @property
    def uses_solver(self) -> bool:
        return self in (Variant.GNN_SOLVER, Variant.FULL, Variant.POST_COL)

    @property
    def uses_handler(self) -> bool:
        return self in (Variant.GNN_COLLISION, Variant.FULL)


class Displacement(str, enum.Enum):
    """How the decoder's first three outputs become the move Δx of X = X_init + Δx."""

    DIRECT = "direct"  # Δx = displacement_scale · output [m]
    PRECONDITIONED = "preconditioned"  # Δx = C (force_scale · output · m g): a force field through the solver's C


@dataclass(frozen=True)
class ModelConfig:
    """Architecture and module settings of `PhysDrape`; the defaults are the shipped model's.

    latent / blocks / mlp_layers: GNN width D, depth L and Linear layers per MLP (paper: 128, 16, 2).
    levels: coarse graph levels of hierarchical message passing (0: the paper's mesh graph; with
    K levels the blocks walk V-cycles over levels 0…K, each level reaching about twice as far as
    the one below, see `gnn.level_schedule` and `topology.coarse_graphs`; the coarse nodes are
    picked in vertex order, so a model with levels is not exactly equivariant to relabelling).
    mesh_blocks: processor blocks on the mesh graph after the V-cycles, before the decoder, each
    starting as the identity (`EncodeProcessDecode`): more local work per pass, addable to a
    trained network (`optim.init_from` keeps them at their start).
    global_context: after each processor block every vertex also gets its garment's summary (an
    MLP of the mean of the garment's latents, `EncodeProcessDecode`; each piece's of a garment with
    a layer order of pieces, `model.physdrape.summary_groups`): garment-wide information in every
    block; the summaries start at zero, addable to a trained network likewise.
    zero_init_output: the decoder's last layer starts at zero (Δx = 0, f̂ = 0 before training).
    train_steps / eval_steps: solver steps T in training and evaluation (paper: 3, 15).
    solver: "two_level" (conjugate directions, block Jacobi plus a coarse correction on smooth
    patches, body contact, a line search) or "explicit" (the paper's Eq. 10, a scalar
    compliance); see `StretchingSolver`. requery_every: two-level steps between body queries;
    refactor_every: two-level steps between factorisations of the coarse space (1: every step,
    the coarse moves follow the garment's stiffness as its strain relaxes, at the cost of a
    factorisation per step; `bench/solver_settings.py` measures both); refactor_first: the first
    steps that factorise at every step, then every refactor_every (X_init's strain relaxes most
    in the first steps, and a factor from X_init holds the coarse moves back after it has;
    `results/solver_settings.md`). follow_planes: at the steps between body queries, find the
    closest body faces of the samples near it (within the solver's contact band of their planes)
    again, by a walk from their last ones, so that the contact planes follow the garment where
    it touches the body instead of being held for requery_every steps. requery_every and
    follow_planes hold in training; eval_requery_every and eval_follow_planes in eval mode
    (validation, evaluation, `Draper`): the planes' schedule changes no weight, and the network
    trained on held planes drapes with a lower E_total on followed ones
    (`results/solver_settings_planes.md`), while training through followed planes teaches it
    moves the solver then takes back (`docs/training/README.md`). follow_min_move: followed planes
    are found again only for the samples that moved more than this [m] since their planes were
    found (0: every near sample at every step; see `StretchingSolver`; 2 mm: on the held-out set
    the same E_total as 1 mm at T = 3 and 15 for 5 % less time per drape,
    `results/solver_settings_follow_min_move_2mm.md`). inner_steps,
    inner_iterations: the first solver steps whose direction is that many preconditioned
    conjugate-gradient iterations on the quadratic model (a truncated Newton step; 1: the plain
    preconditioned step); eval_inner_iterations in eval mode: the shipped model was trained on
    plain steps and drapes with 3 iterations at its first 3 steps
    (`results/solver_settings_inner_iterations.md`).
    f_hat_steps: the solver steps that carry the network's force f̂, its first ones (None: every
    step, the paper's); the later ones relax the garment's own energy, so a long solve ends at
    the physics' equilibrium and not at F = −f̂ (the shipped model's 3 = its train_steps: T = 3
    is unchanged, T = 15 ends lower, `results/eval_drift_f_hat_steps.md`).
    coarse_levels / coarse_smoothing: the two-level solver's patches (`CoarseSpace`).
    contact_band: the two-level solver's contact band [m]: body samples closer to their plane
    than this get the penalty's stiffness at depth ε in its preconditioner (a quadratic model
    then sees the body before the garment enters the margin), and their planes are the ones
    followed between body searches (`StretchingSolver`); the step inputs are read with it in
    every mode, as the network was trained. eval_contact_band: the band of the solver's steps in
    eval mode (None: contact_band). A wide band holds back every sample near the body, also where
    the garment has to settle onto it; a narrow one lets a step that is still large (X_init's
    strain relaxing) run samples into the body (the solver's steps stop a vertex from beyond the
    band at its margin, and a vertex that moved far in the last step gets the band's block up to
    contact_band; `Relaxation`). 7 mm: on the held-out set the bundled model at T = 3 ends at
    1.053 times the teacher drapes' E_total against 1.056 at 1 cm, at T = 15 at 1.014 against
    1.015, lower at every T from 2; the solver alone 1.128 against 1.131 at T = 3, 1.020 against
    1.021 at T = 15 (`results/solver_settings_eval_contact_band.md`; 6 mm there: 1.052, 1.013,
    the solver alone 1.128, 1.019).
    eta / gamma: initial solver step scale (two_level: dimensionless, 1 = a full preconditioned
    step; explicit: a compliance [m/N]) and decay; max_step: the solver's per-vertex step clip [m]
    (stability guard, see `StretchingSolver`; 2 cm lowers E_total at every T against 1 cm,
    `results/solver_settings_max_step.md`). delta: initial handler push factor.
    margin: contact margin ε [m] of the handler, the solver's contact term and the training loss.
    contact_stiffness: penalty stiffness k_c [J/m³] of the solver's contact term and the training
    loss (`physics.contact`). centroid_margin: ε_c [m] of the handler's centroid pass (faces
    whose centroid is closer to the body are pushed out; 0 = the paper's vertex-only handler; see
    `CollisionHandler`).
    displacement: how the decoder's output becomes Δx (`Displacement`). "direct": Δx =
    displacement_scale [m] × the output. "preconditioned": the output is a force field, in units
    of force_scale × each vertex's weight m g, and Δx is that field through the two-level solver's
    preconditioner C at X_init (`StretchingSolver.preconditioner`: block Jacobi on the vertices'
    stiffness plus the coarse correction on smooth patches, body contact included), so that the
    loss's gradient reaches the network as the solver's preconditioned step, and a patch sliding
    or riding up as a whole is a smooth force, where "direct" needs the move vertex by vertex.
    max_move: the preconditioned move's per-vertex length limit [m] (a guard: C's coarse modes
    are soft, so a force field can ask for moves of metres, e.g. through the body).
    passes: network passes, one set of weights: pass k > 1 reads its inputs at the garment the
    passes before it moved (its internal forces, normals, body distances and edges there) and
    adds its move, so it sees and corrects the residual of the passes before it; f̂ is the last
    pass's. Each pass costs a network evaluation and a body query.
    step_inputs: the network also reads, per vertex, the two parts of the two-level solver's
    first step direction at its input positions (`StretchingSolver.step_parts`): the block-Jacobi
    move K⁻¹F (local) and the coarse correction's move (the garment sliding, riding up or
    settling as a whole on smooth patches), six more node features. Message passing alone sees
    the forces, which the stiff local strain dominates; the coarse move says where the garment
    as a whole is pulled. Needs the two_level solver.
    body_normal_inputs: the network also reads, per vertex, the body's unit outward direction at
    the vertex's closest body point (the body query's normal), three more node features after the
    eleven of Eq. 6: the garment's own normal and distance do not say which way the body slopes
    under a loose garment, which decides where the garment slides as it settles.
    step_newton_iterations: with step_inputs, k > 0 adds three more node features: the first
    step's truncated Newton move, k preconditioned conjugate-gradient iterations on the quadratic
    model of the energy at the input positions (as the solver's first steps at inference,
    `eval_inner_iterations`), clipped like the parts. Where K⁻¹F sees each vertex's own stiffness
    only, the Newton move accounts for its neighbours' pull too: the in-plane strain that X_init
    leaves needs moves precise to a fraction of an edge. 0: none.
    eval_move_gain: in eval mode, the solver starts from X_init + g Δx instead of the network's
    drape X_init + Δx (g = 1: the network's drape; the GNN-only drape is X_init + Δx whatever g).
    A network trained on its own drape's energy stops short of the garment-wide move, which the
    solver relaxes slowest, while the strain that a longer move adds is what the solver's first
    steps relax fastest; g is chosen on the held-out validation set (docs/solver.md).
    look_back_blocks: an odd number of processor blocks of a look-back stage after the network's
    blocks (0: none; `EncodeProcessDecode.forward_looking_back`): the network decodes its move
    Δx₁, reads the two-level solver's first step parts at X_init + Δx₁ (on the body planes of its
    input's query, held), encodes them into its latents and adds the move Δx₂ that these blocks
    (a V-cycle over (look_back_blocks − 1) / 2 of the coarse levels, at most `levels`) and a decoder of their own make.
    A second pass's physics at a fraction of a pass's cost: no body query, no graph inputs
    anew, a short V-cycle. The drape X_init + Δx₁ counts as an earlier pass's
    (`DrapeOutput.earlier_passes`, `LossConfig.earlier_passes_weight`). Needs step_inputs and
    the direct displacement.
    normalizer_accumulations: batches of the statistics warm-up after which normalisers freeze.
    variant: which modules run (see `Variant`).
    """

    latent: int = 64
    blocks: int = 8
    mesh_blocks: int = 0
    global_context: bool = False
    mlp_layers: int = 2
    levels: int = 0
    zero_init_output: bool = False
    train_steps: int = 3
    eval_steps: int = 15
    solver: SolverKind = SolverKind.TWO_LEVEL
    eta: float = 1.0
    gamma: float = 0.98
    max_step: float = 2e-2
    requery_every: int = 3
    refactor_every: int = 3
    refactor_first: int = 3
    follow_planes: bool = False
    eval_requery_every: int = 8
    eval_follow_planes: bool = True
    f_hat_steps: int | None = 3
    follow_min_move: float = 2e-3
    inner_steps: int = 3
    inner_iterations: int = 1
    eval_inner_iterations: int = 3
    coarse_levels: int = 2
    coarse_smoothing: int = 2
    contact_band: float = 0.01
    eval_contact_band: float | None = 0.007
    delta: float = 1.05
    margin: float = DEFAULT_MARGIN
    contact_stiffness: float = DEFAULT_STIFFNESS
    centroid_margin: float = 5e-4
    displacement: Displacement = Displacement.DIRECT
    displacement_scale: float = 0.01
    force_scale: float = 1.0
    max_move: float = 0.03
    passes: int = 1
    eval_move_gain: float = 1.0
    step_inputs: bool = False
    body_normal_inputs: bool = False
    step_newton_iterations: int = 0
    look_back_blocks: int = 0
    normalizer_accumulations: int = 100
    variant: Variant = Variant.FULL

    def __post_init__(self) -> None:
        object.__setattr__(self, "variant", Variant(self.variant))
        object.__setattr__(self, "solver", SolverKind(self.solver))
        object.__setattr__(self, "displacement", Displacement(self.displacement))
        if self.max_move < 0:
            raise ValueError(f"ModelConfig.max_move must be ≥ 0 [m] (0: unclipped), got {self.max_move}")
        if self.displacement is Displacement.PRECONDITIONED and self.solver is not SolverKind.TWO_LEVEL:
            raise ValueError("ModelConfig.displacement 'preconditioned' uses the two_level solver's preconditioner; "
                             f"set solver: two_level (got {self.solver.value})")
        if self.step_inputs and self.solver is not SolverKind.TWO_LEVEL:
            raise ValueError("ModelConfig.step_inputs reads the two_level solver's first step; set solver: two_level "
                             f"(got {self.solver.value})")
        k = self.step_newton_iterations
        if isinstance(k, bool) or not isinstance(k, int) or k < 0:
            raise ValueError(f"ModelConfig.step_newton_iterations must be an integer ≥ 0 (0: no Newton move among the "
                             f"inputs), got {k!r}")
        if k and not self.step_inputs:
            raise ValueError("ModelConfig.step_newton_iterations adds to the solver's step parts among the inputs: "
                             "set step_inputs: true")
        if k and self.look_back_blocks:
            raise ValueError("ModelConfig.look_back_blocks reads the two step parts only; set "
                             "step_newton_iterations: 0 with a look-back stage")
        if self.mesh_blocks < 0:
            raise ValueError(f"ModelConfig.mesh_blocks must be ≥ 0, got {self.mesh_blocks}")
        for name in ("latent", "blocks", "mlp_layers"):
            if getattr(self, name) < 1:
                raise ValueError(f"ModelConfig.{name} must be ≥ 1, got {getattr(self, name)}")
        k = self.f_hat_steps
        if k is not None and (isinstance(k, bool) or not isinstance(k, int) or k < 0):
            raise ValueError(f"ModelConfig.f_hat_steps must be an integer ≥ 0 (null: every solver step), got {k!r}")
        if self.inner_steps < 0 or self.inner_iterations < 1 or self.eval_inner_iterations < 1:
            raise ValueError(f"ModelConfig needs inner_steps ≥ 0 and inner_iterations, eval_inner_iterations ≥ 1 "
                             f"(1: the plain preconditioned step), got {self.inner_steps}, {self.inner_iterations}, "
                             f"{self.eval_inner_iterations}")
        if not self.follow_min_move >= 0:
            raise ValueError(f"ModelConfig.follow_min_move must be ≥ 0 [m] (0: every followed sample at every step), "
                             f"got {self.follow_min_move}")
        for name in ("contact_band", "eval_contact_band"):
            band = getattr(self, name)
            if band is not None and not band > 0:
                raise ValueError(f"ModelConfig.{name} must be > 0 [m] (the solver's contact band), got {band}")
        if self.eval_requery_every < 1:
            raise ValueError(f"ModelConfig.eval_requery_every must be ≥ 1 (solver steps), got {self.eval_requery_every}")
        if self.passes < 1:
            raise ValueError(f"ModelConfig.passes must be ≥ 1 (network passes), got {self.passes}")
        if not self.eval_move_gain > 0:
            raise ValueError(f"ModelConfig.eval_move_gain must be > 0 (1: the solver starts from the network's "
                             f"drape), got {self.eval_move_gain}")
        if self.levels < 0:
            raise ValueError(f"ModelConfig.levels must be ≥ 0, got {self.levels}")
        if self.look_back_blocks < 0 or (self.look_back_blocks and self.look_back_blocks % 2 == 0):
            raise ValueError(f"ModelConfig.look_back_blocks must be 0 (no look-back) or odd (a V-cycle that ends on "
                             f"the mesh), got {self.look_back_blocks}")
        if self.look_back_blocks and (not self.step_inputs or self.displacement is not Displacement.DIRECT):
            raise ValueError("ModelConfig.look_back_blocks reads the solver's step parts where the network's direct "
                             "move leaves the garment: set step_inputs: true and displacement: direct")

    @staticmethod
    def paper() -> "ModelConfig":
        """The paper's size: D = 128, L = 16."""
        return ModelConfig(latent=128, blocks=16)

