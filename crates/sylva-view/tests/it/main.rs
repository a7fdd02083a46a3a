//! The viewer's server end to end over real sockets: the token and Origin checks, frames that
//! follow the sun with no LB solve, latest input wins, hostile messages answered while other
//! pages are served, a page that leaves, saving (docs/view.md).

mod protocol;
mod server;
