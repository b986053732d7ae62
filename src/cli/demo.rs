use anyhow::Result;

pub fn run() -> Result<()> {
    anyhow::bail!(
        "the live demo (simulator + gateway over ptys) is not built yet: it arrives with the gateway. \
         Meanwhile `flowgate plan --all scenarios/` runs the planner against the simulated world offline"
    )
}
