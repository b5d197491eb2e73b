"""The deadline over a weaker candidate (policy.deadline_over_weaker): with the budget nearly spent,
the last resort comes before verifying a potential candidate whose evidence is below the best
rejected one's."""

from agent.events import Context
from agent.modes import Mode
from agent.types import Action, Pose2D
from tests.helpers.agent_runs import painted_agent
from tests.helpers.agent_scenes import PaintedWorld, two_rooms

BUDGET = 230


def run(over_weaker: bool, budget: int = BUDGET, window: int = BUDGET):
    """The two-room world of the second look's tests, the goal scoring 20 wherever it is seen and
    the decoy 5 (tau 100, tau/2 50): exploration ends with nothing, the second look forms
    candidates on both, the ring rejects the goal's (20 < 50) and the robot goes on to verify the
    decoy's, far from the goal. The deadline is checked at every step of a 230-step budget; with
    a budget unknown to it the robot finishes the decoy at step 205 and reaches the goal by the
    last resort at step 248. Returns (decisions with records, distance to the goal per step)."""
    boxes, goal, decoy = two_rooms()
    world = PaintedWorld(boxes, Pose2D(-1.5, -1.0, 0.3), goal, decoy=decoy)
    agent, _ = painted_agent(
        world,
        lambda: 20.0,
        exhausted_recheck_frames=8,
        last_resort_at_deadline=True,
        step_budget=budget,
        deadline_window_steps=window,
        deadline_over_weaker=over_weaker,
    )
    obs = world.observe()
    agent.reset(obs.goal_image)
    steps, dist = [], []
    for _ in range(budget):
        action = agent.act(obs)
        steps.append((agent.last_decision, agent.last_record))
        world.apply(action)
        dist.append(world.distance_to_goal())
        if action == Action.STOP:
            break
        obs = world.observe()
    return steps, dist


def test_at_the_deadline_the_better_rejected_candidate_goes_before_a_weaker_potential_one():
    off, off_dist = run(False)
    on, on_dist = run(True)
    # without the switch the robot is still verifying the decoy (best score 5) when the deadline
    # is due, and the budget runs out before the last resort reaches the goal
    assert len(off) == BUDGET and off[-1][0].action != Action.STOP and off_dist[-1] > 1.0
    k = next(i for i, (d, _) in enumerate(on) if d.has(Context.DEADLINE_OVER_WEAKER))
    # the same run up to that step, and there the run without it verifies the weaker candidate
    assert [d.action for d, _ in on[:k]] == [d.action for d, _ in off[:k]]
    d_off, rec_off = off[k]
    assert d_off.mode == Mode.VERIFY and d_off.candidate is not None
    live = {c.id: c for c in rec_off.candidates}
    assert live[d_off.candidate.id].state == "potential" and live[d_off.candidate.id].best_score == 5.0
    assert max(c.best_score for c in rec_off.candidates if c.state == "rejected") == 20.0
    # with it: the last resort to the goal's rejected candidate, said in the record, from then on
    d_on, rec_on = on[k]
    facts = {n.context: dict(n.facts) for n in d_on.context}
    assert d_on.mode == Mode.LAST_RESORT and rec_on.context == ("deadline_over_weaker", "last_resort")
    assert facts == {
        Context.DEADLINE_OVER_WEAKER: {"steps_left": BUDGET - k, "score": 5.0},
        Context.LAST_RESORT: {"score": 20.0},
    }
    assert all(d.mode in (Mode.LAST_RESORT, Mode.STOPPED) for d, _ in on[k:])
    # ... and it stops at the goal within the budget
    last, rec = on[-1]
    assert last.action == Action.STOP and last.mode == Mode.STOPPED and len(on) < BUDGET
    assert on_dist[-1] < 1.0


def test_it_does_not_act_before_the_deadline():
    # a budget of 1000 checked in its last 200 steps: the run ends (step 248) long before the
    # window opens, so the switch changes nothing, action for action
    on, _ = run(True, budget=1000, window=200)
    off, _ = run(False, budget=1000, window=200)
    assert [d.action for d, _ in on] == [d.action for d, _ in off]
    assert [(d.event, d.context) for d, _ in on] == [(d.event, d.context) for d, _ in off]
    assert on[-1][0].mode == Mode.STOPPED and len(on) < 300
    assert not any(d.has(Context.DEADLINE) or d.has(Context.DEADLINE_OVER_WEAKER) for d, _ in on)
