//! Internal forces over ranks that share nothing (Algorithm 1 of Ni, Kale,
//! Tamstorf 2015), on threads that stand in for processes.
//!
//! Each rank keeps its own copy of positions, velocities and output slots in
//! which only what it owns or has received is valid — everything else is NaN,
//! so a read of data that never arrived poisons the result and the bitwise
//! comparison with the shared-memory fold fails. Per tick a rank
//!
//! 1. sends the state (x, v) of its vertices that peers read as ghosts;
//! 2. evaluates its interior partitions while those messages travel;
//! 3. receives its ghosts and evaluates its boundary partitions;
//! 4. sends the slots that peers' vertices fold;
//! 5. folds (in global key order) and advances the vertices whose slots are
//!    all local, then receives the remote slots and does the rest.
//!
//! Every message is tagged with its tick and sender; channels keep order per
//! sender, and early arrivals are held until wanted. The MPI executor will
//! swap the channels for nonblocking sends and receives.

use std::collections::HashMap;
use std::sync::mpsc;

use glam::DVec3;
use weft_sim::World;

use super::plan::RankPlan;
use super::transport::Traffic;

enum Payload {
    /// (x, v) of the sender's listed vertices.
    State(Vec<[DVec3; 2]>),
    /// The sender's listed slots.
    Slots(Vec<DVec3>),
}

/// A vertex a rank owns, with its final position and velocity.
type OwnedState = (u32, DVec3, DVec3);

struct Message {
    tick: usize,
    from: u32,
    payload: Payload,
}

/// One explicit step of vertex `i` from its folded internal force `fold`:
/// `v += -h (fold - m g) / m`, then `x += h v` (the engine's internal kick
/// without contact, followed by a drift of one step).
pub fn advance(world: &World, i: usize, fold: DVec3, x: &mut DVec3, v: &mut DVec3, h: f64) {
    if world.inv_mass[i] > 0.0 {
        let g = fold - world.gravity * world.mass[i];
        *v += (g * -h) * world.inv_mass[i];
    }
    *x += *v * h;
}

/// Runs `ticks` internal steps of `world`'s cloth on the ranks of `plans`;
/// returns the final positions and velocities of every owned vertex (NaN for
/// the others: obstacles) and what each rank sent.
pub fn run_ticks(
    world: &World,
    plans: &[RankPlan],
    ticks: usize,
) -> (Vec<DVec3>, Vec<DVec3>, Vec<Traffic>) {
    let n = world.num_vertices();
    let h = world.lattice.h_el();
    let (senders, receivers): (Vec<_>, Vec<_>) =
        (0..plans.len()).map(|_| mpsc::channel::<Message>()).unzip();
    let results: Vec<(Vec<OwnedState>, Traffic)> = std::thread::scope(|scope| {
        let handles: Vec<_> = receivers
            .into_iter()
            .enumerate()
            .map(|(r, inbox)| {
                let senders = senders.clone();
                let plan = &plans[r];
                scope.spawn(move || rank_main(world, plan, r as u32, &senders, inbox, ticks, h))
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("a rank panicked"))
            .collect()
    });
    let mut x = vec![DVec3::NAN; n];
    let mut v = vec![DVec3::NAN; n];
    let mut traffic = Vec::with_capacity(results.len());
    for (owned, t) in results {
        for (i, xi, vi) in owned {
            x[i as usize] = xi;
            v[i as usize] = vi;
        }
        traffic.push(t);
    }
    (x, v, traffic)
}

fn rank_main(
    world: &World,
    plan: &RankPlan,
    me: u32,
    peers: &[mpsc::Sender<Message>],
    inbox: mpsc::Receiver<Message>,
    ticks: usize,
    h: f64,
) -> (Vec<OwnedState>, Traffic) {
    let internal = &world.internal;
    let n = world.num_vertices();
    let mut x = vec![DVec3::NAN; n];
    let mut v = vec![DVec3::NAN; n];
    for &i in &plan.owned {
        x[i as usize] = world.x[i as usize];
        v[i as usize] = world.v[i as usize];
    }
    let mut out = vec![DVec3::NAN; internal.num_slots()];
    let mut traffic = Traffic::default();
    let mut held: HashMap<(usize, bool, u32), Payload> = HashMap::new();
    let send = |to: u32, tick: usize, payload: Payload, traffic: &mut Traffic| {
        traffic.messages += 1;
        traffic.bytes += match &payload {
            Payload::State(s) => (s.len() * 48) as u64,
            Payload::Slots(s) => (s.len() * 24) as u64,
        };
        peers[to as usize]
            .send(Message {
                tick,
                from: me,
                payload,
            })
            .expect("a peer rank is gone");
    };
    // Waits for the (tick, kind, from) message, holding others that arrive.
    let mut receive = |tick: usize, state: bool, from: u32| -> Payload {
        if let Some(p) = held.remove(&(tick, state, from)) {
            return p;
        }
        loop {
            let m = inbox.recv().expect("a peer rank is gone");
            let is_state = matches!(m.payload, Payload::State(_));
            if (m.tick, is_state, m.from) == (tick, state, from) {
                return m.payload;
            }
            held.insert((m.tick, is_state, m.from), m.payload);
        }
    };
    let (boundary, interior) = plan.partitions.split_at(plan.boundary);
    let evaluate = |p: usize, x: &[DVec3], v: &[DVec3], out: &mut [DVec3]| {
        let slots = internal.partitions[p].slots.clone();
        internal.evaluate_partition(p, x, v, &mut out[slots]);
    };
    for tick in 0..ticks {
        for (&peer, list) in &plan.send_state {
            let data = list
                .iter()
                .map(|&i| [x[i as usize], v[i as usize]])
                .collect();
            send(peer, tick, Payload::State(data), &mut traffic);
        }
        let _span = weft_sim::trace::span_with("rank tick", "rank", me as u64);
        for &p in interior {
            evaluate(p, &x, &v, &mut out);
        }
        for (&peer, list) in &plan.recv_state {
            let Payload::State(data) = receive(tick, true, peer) else {
                unreachable!("matched on the kind")
            };
            for (&i, [xi, vi]) in list.iter().zip(data) {
                x[i as usize] = xi;
                v[i as usize] = vi;
            }
        }
        for &p in boundary {
            evaluate(p, &x, &v, &mut out);
        }
        for (&peer, list) in &plan.send_slots {
            let data = list.iter().map(|&s| out[s as usize]).collect();
            send(peer, tick, Payload::Slots(data), &mut traffic);
        }
        for &i in &plan.interior_vertices {
            let i = i as usize;
            let f = internal.fold(i, &out);
            advance(world, i, f, &mut x[i], &mut v[i], h);
        }
        for (&peer, list) in &plan.recv_slots {
            let Payload::Slots(data) = receive(tick, false, peer) else {
                unreachable!("matched on the kind")
            };
            for (&s, value) in list.iter().zip(data) {
                out[s as usize] = value;
            }
        }
        for &i in &plan.boundary_vertices {
            let i = i as usize;
            let f = internal.fold(i, &out);
            advance(world, i, f, &mut x[i], &mut v[i], h);
        }
    }
    let owned = plan
        .owned
        .iter()
        .map(|&i| (i, x[i as usize], v[i as usize]))
        .collect();
    (owned, traffic)
}
