//! `cargo xtask deps`: the crates' dependency graph keeps its shape.
//!
//! * no cycle among the repository's crates, dev-dependencies included;
//! * no test crate (`stjpdacf-test-support`) in the normal or build dependencies of a crate that
//!   is not a test crate (the fuzz targets are test crates);
//! * the f64 reference (`stjpdacf-reference`) does not depend on the core: it is the oracle;
//! * the core (`stjpdacf`) depends on no crate of the repository.

use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;

use anyhow::{bail, ensure, Context, Result};
use serde::Deserialize;
use stjpdacf_tools::repo_root;

/// The test crates.
const TEST_CRATES: [&str; 2] = ["stjpdacf-test-support", "stjpdacf-fuzz"];

#[derive(Deserialize)]
struct Metadata {
    packages: Vec<Package>,
}

#[derive(Deserialize)]
struct Package {
    name: String,
    source: Option<String>,
    dependencies: Vec<Dependency>,
}

#[derive(Deserialize)]
struct Dependency {
    name: String,
    kind: Option<String>,
    path: Option<String>,
}

/// The repository's crates (path dependencies) of the workspace at `manifest` and their edges
/// to other repository crates: `(name, [(dependency, kind)])`.
fn local_graph(manifest: &str) -> Result<BTreeMap<String, Vec<(String, String)>>> {
    let out = Command::new("cargo")
        .current_dir(repo_root())
        .args([
            "metadata",
            "--format-version",
            "1",
            "--no-deps",
            "--manifest-path",
            manifest,
        ])
        .output()
        .context("cargo metadata")?;
    ensure!(
        out.status.success(),
        "cargo metadata {manifest}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let m: Metadata = serde_json::from_slice(&out.stdout).context("cargo metadata output")?;
    Ok(m.packages
        .into_iter()
        .filter(|p| p.source.is_none())
        .map(|p| {
            let edges = p
                .dependencies
                .into_iter()
                .filter(|d| d.path.is_some())
                .map(|d| (d.name, d.kind.unwrap_or_else(|| "normal".into())))
                .collect();
            (p.name, edges)
        })
        .collect())
}

fn find_cycle(g: &BTreeMap<String, Vec<(String, String)>>) -> Option<Vec<String>> {
    fn visit(
        n: &str,
        g: &BTreeMap<String, Vec<(String, String)>>,
        done: &mut BTreeSet<String>,
        path: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = path.iter().position(|p| p == n) {
            return Some(path.get(i..).map(<[String]>::to_vec).unwrap_or_default());
        }
        if done.contains(n) {
            return None;
        }
        path.push(n.to_owned());
        for (d, _) in g.get(n).map(Vec::as_slice).unwrap_or_default() {
            if let Some(c) = visit(d, g, done, path) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(n.to_owned());
        None
    }
    let mut done = BTreeSet::new();
    g.keys()
        .find_map(|n| visit(n, g, &mut done, &mut Vec::new()))
}

/// `cargo xtask deps`.
pub fn check() -> Result<()> {
    let mut g = BTreeMap::new();
    for manifest in ["Cargo.toml", "fuzz/Cargo.toml", "bench/firmware/Cargo.toml"] {
        g.extend(local_graph(manifest)?);
    }
    let mut problems = Vec::new();
    if let Some(c) = find_cycle(&g) {
        problems.push(format!("dependency cycle: {}", c.join(" → ")));
    }
    for (name, edges) in &g {
        for (d, kind) in edges {
            let test_dep = TEST_CRATES.contains(&d.as_str()) && kind != "dev";
            if test_dep && !TEST_CRATES.contains(&name.as_str()) {
                problems.push(format!(
                    "{name} has the test crate {d} as a {kind} dependency"
                ));
            }
            if name == "stjpdacf-reference" && d == "stjpdacf" {
                problems.push("stjpdacf-reference depends on the core".into());
            }
            if name == "stjpdacf" {
                problems.push(format!("the core depends on the repository crate {d}"));
            }
        }
    }
    for (name, edges) in &g {
        let ds: Vec<String> = edges
            .iter()
            .map(|(d, k)| {
                if k == "normal" {
                    d.clone()
                } else {
                    format!("{d} ({k})")
                }
            })
            .collect();
        println!(
            "{name} → {}",
            if ds.is_empty() {
                "—".into()
            } else {
                ds.join(", ")
            }
        );
    }
    if !problems.is_empty() {
        bail!("dependency graph:\n  {}", problems.join("\n  "));
    }
    println!("dependency graph: no cycle, no test crate under a non-test crate, reference independent of the core");
    Ok(())
}
