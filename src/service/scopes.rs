//! What each API key may do, and what each endpoint needs. Three scopes: `read` (estimate, detect,
//! track, list and get objects, the OpenAPI document), `write` (onboard, delete, and the
//! onboarding operations that writing starts), `admin` (the metrics). A key names its
//! scopes in the key file; a bare key has all three, as every key had before scopes.
//! The tables below are the single source of the mapping (docs/service.md repeats it);
//! their tests check that every route of the OpenAPI document and every RPC of the proto
//! has an entry, so a new endpoint cannot be left to a default.

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Scope {
    Read,
    Write,
    Admin,
}

impl Scope {
    pub const ALL: [Scope; 3] = [Scope::Read, Scope::Write, Scope::Admin];

    pub fn name(self) -> &'static str {
        match self {
            Scope::Read => "read",
            Scope::Write => "write",
            Scope::Admin => "admin",
        }
    }

    fn bit(self) -> u8 {
        1 << self as u8
    }
}

impl std::str::FromStr for Scope {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Scope::ALL.into_iter().find(|x| x.name() == s).ok_or_else(|| format!("unknown scope {s:?} (scopes: read, write, admin)"))
    }
}

/// A set of scopes.
#[derive(Clone, Copy, PartialEq, Eq, Default)]
pub struct Scopes(u8);

impl Scopes {
    pub fn all() -> Self {
        Scope::ALL.into_iter().collect()
    }

    pub fn has(self, s: Scope) -> bool {
        self.0 & s.bit() != 0
    }

    /// `read,write` → those two; empty or unknown names are refused.
    pub fn parse(list: &str) -> Result<Self, String> {
        if list.trim().is_empty() {
            return Err("no scope given (scopes: read, write, admin)".into());
        }
        list.split(',').map(|s| s.trim().parse::<Scope>()).collect()
    }
}

impl FromIterator<Scope> for Scopes {
    fn from_iter<I: IntoIterator<Item = Scope>>(it: I) -> Self {
        Scopes(it.into_iter().fold(0, |acc, s| acc | s.bit()))
    }
}

impl std::fmt::Debug for Scopes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let names: Vec<&str> = Scope::ALL.into_iter().filter(|s| self.has(*s)).map(Scope::name).collect();
        write!(f, "{}", names.join(","))
    }
}

/// What a request needs beyond reaching the server.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Needs {
    /// Open even with keys configured (health checks).
    Nothing,
    /// A known key with this scope.
    Scope(Scope),
    /// A known key, any scope: requests no route matched (answered 404 / 405), so that
    /// an unknown caller learns nothing about which paths exist.
    AnyKey,
}

/// The HTTP table, by method and route template (as axum's `MatchedPath` gives it).
pub fn http(method: &str, route: &str) -> Needs {
    use Needs::Scope as S;
    use Scope::*;
    // axum answers HEAD with the GET handler (body dropped): it needs what GET needs.
    let method = if method == "HEAD" { "GET" } else { method };
    match (method, route) {
        ("GET", "/healthz" | "/readyz") => Needs::Nothing,
        // The console's static files: the page holds no data, and asks for the key.
        ("GET", "/" | "/console" | "/console/" | "/console/{file}") => Needs::Nothing,
        // Who the key is: any known key may ask.
        ("GET", "/v1/caller") => Needs::AnyKey,
        ("GET", "/v1/objects" | "/v1/objects/{id}" | "/v1/objects/{id}/thumbnail" | "/openapi.json") => S(Read),
        ("POST", "/v1/estimate" | "/v1/detect") => S(Read),
        ("GET" | "POST", "/v1/tracks") | ("GET" | "DELETE", "/v1/tracks/{id}") | ("POST", "/v1/tracks/{id}/frames") => S(Read),
        ("POST", "/v1/objects") | ("DELETE", "/v1/objects/{id}") => S(Write),
        ("GET", "/v1/operations/{id}") | ("POST", "/v1/operations/{id}/cancel") => S(Write),
        ("GET", "/metrics") => S(Admin),
        _ => Needs::AnyKey,
    }
}

/// The gRPC table for `b2tfpose.v1.PoseService`, by method name. The health service and
/// reflection are not behind the key check at all (they only describe the server).
pub fn grpc(method: &str) -> Needs {
    use Needs::Scope as S;
    use Scope::*;
    match method {
        "Estimate" | "Detect" | "ListObjects" | "GetObject" | "Track" => S(Read),
        "Onboard" | "DeleteObject" | "GetOperation" | "WatchOperation" | "CancelOperation" => S(Write),
        _ => Needs::AnyKey,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_scope_lists() {
        let s = Scopes::parse("read, admin").unwrap();
        assert!(s.has(Scope::Read) && s.has(Scope::Admin) && !s.has(Scope::Write));
        assert_eq!(format!("{s:?}"), "read,admin");
        assert_eq!(format!("{:?}", Scopes::all()), "read,write,admin");
        assert!(Scopes::parse("read,delete").unwrap_err().contains("\"delete\""));
        assert!(Scopes::parse("").unwrap_err().contains("no scope"));
        assert!(Scopes::parse("read,").is_err());
    }

    #[test]
    fn every_openapi_route_has_an_entry() {
        let doc: serde_json::Value = serde_json::from_str(super::super::http::OPENAPI).unwrap();
        let mut n = 0;
        for (path, ops) in doc["paths"].as_object().unwrap() {
            for method in ops.as_object().unwrap().keys() {
                let needs = http(&method.to_uppercase(), path);
                // The document states the scope of each operation, as the table does;
                // "any" (any known key) is stated, not a default a new route falls into.
                let stated = ops[method]["x-scope"].as_str();
                match needs {
                    Needs::Scope(s) => assert_eq!(stated, Some(s.name()), "{method} {path}"),
                    Needs::AnyKey => assert_eq!(stated, Some("any"), "{method} {path} is not in the scope table"),
                    Needs::Nothing => assert_eq!(stated, None, "{method} {path}"),
                }
                n += 1;
            }
        }
        assert_eq!(n, 19);
        assert_eq!(http("PUT", "/v1/objects"), Needs::AnyKey);
        assert_eq!(http("HEAD", "/metrics"), Needs::Scope(Scope::Admin));
    }

    #[test]
    fn every_rpc_has_an_entry() {
        let proto = include_str!("../../proto/b2tfpose/v1/pose_service.proto");
        let rpcs: Vec<&str> = proto.lines().filter_map(|l| l.trim().strip_prefix("rpc ")).map(|l| l.split('(').next().unwrap().trim()).collect();
        assert_eq!(rpcs.len(), 10, "{rpcs:?}");
        for rpc in rpcs {
            assert_ne!(grpc(rpc), Needs::AnyKey, "{rpc} is not in the scope table");
        }
    }
}
