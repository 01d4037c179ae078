fn main() {
    eprintln!("ladar-odometer: the command line arrives with the daemon issue");
    std::process::exit(2);
}
